//! The immersed circle (`diffphys_flow::immersed`): its forcing is a linear
//! operator on the faces whose adjoint passes the dot-product test, its
//! gradient with respect to the circle matches central differences, the
//! gradient of a loss through 20 steps of a channel flow past it (with respect
//! to the initial velocity, the inflow and the circle's centre and radius)
//! matches central differences to 1e-5, and bad input is a typed error.

mod common;

use std::sync::Arc;

use diffphys_flow::immersed::{immersed_forcing, immersed_forcing_vjp, ImmersedForcing};
use diffphys_flow::{
    Circle, FlowError, FlowParams, FlowState, FlowVars, ForcingScheme, ImmersedCircle, Interior,
    ParamVars, Scene, Sides,
};
use diffphys_tape::{test_array, ArrayD, Schedule, Tape};
use ndarray::{arr1, Array1, Array2};

use common::immersed::{dot, scene, scene_scheme, scene_with, shape, CENTRE, RADIUS};

#[test]
fn the_body_forces_the_free_faces_next_to_it() {
    let scene = scene(shape());
    let body = scene.immersed().unwrap();
    let (nx, ny) = body.forced_count();
    // a circle 4.8 cells across: about π d / h ≈ 15 faces of each component
    assert!(nx >= 10 && ny >= 10, "{nx} {ny}");
    let (ux, uy) = common::velocity(&scene, 1.0, 3);
    let s = arr1(&shape());
    let (fx, fy) = immersed_forcing(body, ux.view(), uy.view(), s.view()).unwrap();
    let (mx, my) = body.forced_mask();
    // unforced faces pass through; forced ones are damped towards the wall
    for (u, f, m) in [(&ux, &fx, &mx), (&uy, &fy, &my)] {
        for ((a, b), k) in u.iter().zip(f).zip(m) {
            if *k == 0.0 {
                assert_eq!(a, b);
            }
        }
        assert!(f.iter().zip(m).any(|(v, k)| *k == 1.0 && *v != 0.0));
    }
}

#[test]
fn the_forcing_passes_the_dot_product_test() {
    for interior in [Interior::Solid, Interior::Forced, Interior::Closed] {
        forcing_passes_the_dot_product_test(&scene_with(shape(), interior));
    }
}

fn forcing_passes_the_dot_product_test(scene: &Scene) {
    let body = scene.immersed().unwrap();
    let s = arr1(&shape());
    let (ux, uy) = common::velocity(scene, 1.0, 5);
    let (gx, gy) = common::velocity(scene, 1.0, 7);
    let (ax, ay) = immersed_forcing(body, ux.view(), uy.view(), s.view()).unwrap();
    let (jx, jy, _) =
        immersed_forcing_vjp(body, ux.view(), uy.view(), s.view(), gx.view(), gy.view()).unwrap();
    // <A u, g> = <u, Aᵀ g> at a fixed circle
    let lhs = dot(&ax, &gx) + dot(&ay, &gy);
    let rhs = dot(&ux, &jx) + dot(&uy, &jy);
    assert!(
        (lhs - rhs).abs() <= 1e-12 * lhs.abs().max(1.0),
        "{lhs} {rhs}"
    );
}

#[test]
fn the_shape_gradient_of_the_forcing_matches_central_differences() {
    let scene = scene(shape());
    let body = scene.immersed().unwrap();
    let (ux, uy) = common::velocity(&scene, 1.0, 9);
    let (gx, gy) = common::velocity(&scene, 1.0, 11);
    let loss = |s: [f64; 3]| {
        let (ax, ay) = immersed_forcing(body, ux.view(), uy.view(), arr1(&s).view()).unwrap();
        dot(&ax, &gx) + dot(&ay, &gy)
    };
    let (_, _, js) = immersed_forcing_vjp(
        body,
        ux.view(),
        uy.view(),
        arr1(&shape()).view(),
        gx.view(),
        gy.view(),
    )
    .unwrap();
    for k in 0..3 {
        let eps = 1e-6;
        let (mut up, mut down) = (shape(), shape());
        up[k] += eps;
        down[k] -= eps;
        let fd = (loss(up) - loss(down)) / (2.0 * eps);
        assert!(js[k].abs() > 1e-3, "shape {k}: gradient {}", js[k]);
        assert!(
            (fd - js[k]).abs() <= 1e-7 * fd.abs().max(1.0),
            "shape {k}: fd {fd} vs vjp {}",
            js[k]
        );
    }
}

/// A forced interior: no cell is solid, every face inside the circle comes
/// out of the forcing at zero, and the step's force is minus the momentum
/// the forcing changed, per unit time.
#[test]
fn a_forced_interior_is_fluid_and_its_force_is_the_forcings_momentum() {
    let scene = scene_with(shape(), Interior::Forced);
    assert!(scene.solid().iter().all(|&c| !c));
    let body = scene.immersed().unwrap();
    let (ux, uy) = common::velocity(&scene, 1.0, 41);
    let s = arr1(&shape());
    let (fx, fy) = immersed_forcing(body, ux.view(), uy.view(), s.view()).unwrap();
    let g = scene.grid();
    let inside =
        |[x, y]: [f64; 2]| (x - CENTRE[0]).powi(2) + (y - CENTRE[1]).powi(2) < RADIUS * RADIUS;
    let mut zeros = 0;
    for ((i, j), v) in fx.indexed_iter() {
        if inside([i as f64 * g.dx, (j as f64 + 0.5) * g.dy]) {
            assert_eq!(*v, 0.0, "x-face ({i}, {j})");
            zeros += 1;
        }
    }
    for ((i, j), v) in fy.indexed_iter() {
        if inside([(i as f64 + 0.5) * g.dx, j as f64 * g.dy]) {
            assert_eq!(*v, 0.0, "y-face ({i}, {j})");
            zeros += 1;
        }
    }
    // a circle 4.8 cells across holds about 2 π r² / h² ≈ 29 faces
    assert!(zeros > 20, "{zeros}");
    // Σ (u' − u) dx dy, every face (the unforced ones do not change)
    let change = |a: &Array2<f64>, b: &Array2<f64>| {
        g.dx * g.dy * a.iter().zip(b).map(|(x, y)| y - x).sum::<f64>()
    };
    let m = body.momentum_change((ux.view(), uy.view()), (fx.view(), fy.view()));
    assert!((m[0] - change(&ux, &fx)).abs() < 1e-12 && (m[1] - change(&uy, &fy)).abs() < 1e-12);
    // the op adds it up over its forwards
    let op = ImmersedForcing::new(Arc::clone(body));
    let tape = Tape::<f64>::new();
    let (a, b) = (
        tape.constant(ux.clone().into_dyn()),
        tape.constant(uy.clone().into_dyn()),
    );
    let c = tape.constant(s.clone().into_dyn());
    tape.apply_multi(op.clone(), &[a, b, c]).unwrap();
    tape.apply_multi(op.clone(), &[a, b, c]).unwrap();
    let t = op.impulse.total();
    assert!((t[0] - 2.0 * m[0]).abs() < 1e-12 && (t[1] - 2.0 * m[1]).abs() < 1e-12);
    // a step reports −Σ (u' − u*) dx dy / dt, with u* its own velocity
    let s0 = FlowState::from_velocity(&scene, ux.clone(), uy.clone());
    let (_, info) = scene.forward(&s0, &scene.params()).unwrap();
    assert!(info
        .immersed_force
        .iter()
        .all(|f| f.is_finite() && *f != 0.0));
    // a scene without an immersed body reports no force
    let plain = common::channel().build().unwrap();
    let (_, info) = plain
        .forward(&FlowState::<f64>::zeros(&plain), &plain.params())
        .unwrap();
    assert_eq!(info.immersed_force, [0.0; 2]);
}

/// A closed interior: the faces the forcing zeroes are closed in the
/// pressure operator too, so a whole step (projection included) leaves every
/// face inside the circle at zero; no cell is solid for the velocity, and
/// without a closed face the pressure's force on them is zero.
#[test]
fn a_closed_interior_leaves_the_faces_inside_the_circle_at_zero_after_the_step() {
    let scene = scene_with(shape(), Interior::Closed);
    assert!(scene.solid().iter().all(|&c| !c));
    let (ux, uy) = common::velocity(&scene, 1.0, 43);
    let s0 = FlowState::from_velocity(&scene, ux, uy);
    let (s1, _) = scene.forward(&s0, &scene.params()).unwrap();
    let g = scene.grid();
    let inside =
        |[x, y]: [f64; 2]| (x - CENTRE[0]).powi(2) + (y - CENTRE[1]).powi(2) < RADIUS * RADIUS;
    let mut zeros = 0;
    for ((i, j), v) in s1.ux.indexed_iter() {
        if inside([i as f64 * g.dx, (j as f64 + 0.5) * g.dy]) {
            assert_eq!(*v, 0.0, "x-face ({i}, {j})");
            zeros += 1;
        }
    }
    for ((i, j), v) in s1.uy.indexed_iter() {
        if inside([(i as f64 + 0.5) * g.dx, j as f64 * g.dy]) {
            assert_eq!(*v, 0.0, "y-face ({i}, {j})");
            zeros += 1;
        }
    }
    assert!(zeros > 20, "{zeros}");
    let force = scene
        .immersed()
        .unwrap()
        .closed_pressure_force(s1.pressure.view());
    assert!(
        force.iter().all(|f| f.is_finite() && *f != 0.0),
        "{force:?}"
    );
    // a forced interior (the pressure spans the body) moves them off zero
    let open = scene_with(shape(), Interior::Forced);
    let (s1, _) = open.forward(&s0, &open.params()).unwrap();
    let moved = s1
        .ux
        .indexed_iter()
        .any(|((i, j), v)| inside([i as f64 * g.dx, (j as f64 + 0.5) * g.dy]) && *v != 0.0);
    assert!(moved);
    let none = open
        .immersed()
        .unwrap()
        .closed_pressure_force(s1.pressure.view());
    assert_eq!(none, [0.0; 2]);
}

const STEPS: usize = 20;

/// `<u_x, w_x> + <u_y, w_y>` of the state after [`STEPS`] steps of the
/// channel past the circle of `shape`, without a tape.
fn loss_after_steps(
    (shape, interior, scheme): ([f64; 3], Interior, ForcingScheme),
    s0: &FlowState<f64>,
    p: &FlowParams<f64>,
    w: &(Array2<f64>, Array2<f64>),
) -> f64 {
    let scene = scene_scheme(shape, interior, scheme);
    let mut s = s0.clone();
    for _ in 0..STEPS {
        s = scene.forward(&s, p).unwrap().0;
    }
    dot(&s.ux, &w.0) + dot(&s.uy, &w.1)
}

#[test]
fn gradients_through_twenty_steps_match_central_differences() {
    gradients_through_twenty_steps(Interior::Solid, ForcingScheme::Direct);
}

#[test]
fn gradients_through_twenty_steps_with_a_forced_interior_match_central_differences() {
    gradients_through_twenty_steps(Interior::Forced, ForcingScheme::Direct);
}

#[test]
fn gradients_through_twenty_steps_with_a_closed_interior_match_central_differences() {
    gradients_through_twenty_steps(Interior::Closed, ForcingScheme::Direct);
}

#[test]
fn gradients_through_twenty_multi_direct_steps_match_central_differences() {
    for interior in [Interior::Forced, Interior::Solid, Interior::Closed] {
        gradients_through_twenty_steps(interior, ForcingScheme::MultiDirect { passes: 3 });
    }
}

#[test]
fn gradients_through_twenty_consistently_forced_steps_match_central_differences() {
    gradients_through_twenty_steps(Interior::Forced, ForcingScheme::ProjectionConsistent);
    gradients_through_twenty_steps(Interior::Solid, ForcingScheme::ProjectionConsistent);
}

/// The gradient of a loss after [`STEPS`] steps with respect to the initial
/// velocity, the inflow, the centre and the radius, against central
/// differences.
fn gradients_through_twenty_steps(interior: Interior, scheme: ForcingScheme) {
    let scene = scene_scheme(shape(), interior, scheme);
    let (ux, uy) = common::velocity(&scene, 0.3, 21);
    let s0 = FlowState::from_velocity(&scene, ux, uy);
    let p = scene.params::<f64>();
    let w = common::velocity(&scene, 1.0, 31);

    let tape = Tape::<f64>::new();
    let state = FlowVars::variables(&tape, &s0);
    let params = ParamVars::variables(&tape, &p);
    let body = tape.var(arr1(&shape()).into_dyn());
    let mut s = state.clone();
    for _ in 0..STEPS {
        s = scene.step_with_body(&tape, &s, &params, body).unwrap().0;
    }
    let wx = tape.constant(w.0.clone().into_dyn());
    let wy = tape.constant(w.1.clone().into_dyn());
    let loss = s.ux.dot(wx).unwrap().add(s.uy.dot(wy).unwrap()).unwrap();
    let value = loss.item().unwrap();
    assert!(
        (value - loss_after_steps((shape(), interior, scheme), &s0, &p, &w)).abs()
            <= 1e-12 * value.abs()
    );
    let g = tape
        .backward(loss, &[state.ux, state.uy, params.inflow, body])
        .unwrap();

    let (dx, dy) = common::velocity(&scene, 1.0, 23);
    let dinflow: Array1<f64> = test_array::<f64>(&[scene.inflow_len()], 24)
        .into_dimensionality()
        .unwrap();
    let central = |eps: f64, run: &dyn Fn(f64) -> f64| (run(eps) - run(-eps)) / (2.0 * eps);
    let sum = |a: &ArrayD<f64>, b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let along_shape = |k: usize| {
        central(1e-6, &|e| {
            let mut s = shape();
            s[k] += e;
            loss_after_steps((s, interior, scheme), &s0, &p, &w)
        })
    };
    let g_body = g.get(body).unwrap();
    let cases = [
        (
            "initial velocity",
            central(1e-6, &|e| {
                let mut s = s0.clone();
                s.ux.scaled_add(e, &dx);
                s.uy.scaled_add(e, &dy);
                loss_after_steps((shape(), interior, scheme), &s, &p, &w)
            }),
            sum(g.get(state.ux).unwrap(), dx.as_slice().unwrap())
                + sum(g.get(state.uy).unwrap(), dy.as_slice().unwrap()),
        ),
        (
            "inflow profile",
            central(1e-6, &|e| {
                let mut q = p.clone();
                q.inflow.scaled_add(e, &dinflow);
                loss_after_steps((shape(), interior, scheme), &s0, &q, &w)
            }),
            sum(g.get(params.inflow).unwrap(), dinflow.as_slice().unwrap()),
        ),
        ("centre x", along_shape(0), g_body[0]),
        ("centre y", along_shape(1), g_body[1]),
        ("radius", along_shape(2), g_body[2]),
    ];
    for (what, fd, ad) in cases {
        println!("{interior:?}, {scheme:?}: d loss / d {what}: finite differences {fd:.10e}, tape {ad:.10e}");
        assert!(
            ad.abs() > 1e-4,
            "{what}: the gradient is (nearly) zero: {ad:e}"
        );
        assert!(
            (fd - ad).abs() <= 1e-5 * fd.abs().max(1e-3),
            "{what}: fd {fd:e} vs tape {ad:e}"
        );
    }
}

#[test]
fn bad_bodies_are_typed_errors() {
    assert!(matches!(
        Circle::new([0.5, 0.5], 0.0),
        Err(FlowError::InvalidParameter { .. })
    ));
    assert!(matches!(
        Circle::new([0.5, 0.5], -0.1),
        Err(FlowError::InvalidParameter { .. })
    ));
    assert!(matches!(
        Circle::new([f64::NAN, 0.5], 0.1),
        Err(FlowError::NonFinite { .. })
    ));
    assert!(matches!(
        Circle::from_shape(&[0.5, 0.1]),
        Err(FlowError::Shape { .. })
    ));
    // outside the domain, or too small for the grid: the scene refuses it
    let outside = Circle {
        center: [1.9, 0.5],
        radius: 0.2,
    };
    let built = Scene::builder(24, 12, [2.0, 1.0])
        .sides(Sides::channel())
        .immersed(outside)
        .parabolic_inflow(1.0)
        .build();
    assert!(
        matches!(built, Err(FlowError::InvalidScene { .. })),
        "{built:?}"
    );
    let tiny = Circle {
        center: [1.0, 0.5],
        radius: 0.01,
    };
    let built = Scene::builder(24, 12, [2.0, 1.0]).immersed(tiny).build();
    assert!(
        matches!(built, Err(FlowError::InvalidScene { .. })),
        "{built:?}"
    );

    let scene = scene(shape());
    let grid = scene.grid();
    let wrong_mask = Array2::from_elem((3, 3), false);
    let c = Circle::new(CENTRE, RADIUS).unwrap();
    let made = ImmersedCircle::new(grid, scene.faces(), &wrong_mask, c);
    assert!(matches!(made, Err(FlowError::Shape { .. })));
    let far = Circle::new([5.0, 0.5], 0.2).unwrap();
    let made = ImmersedCircle::new(grid, scene.faces(), scene.solid(), far);
    assert!(matches!(made, Err(FlowError::InvalidScene { .. })));

    // a body value on the tape that is not a circle
    let s0 = FlowState::zeros(&scene);
    let p = scene.params::<f64>();
    for (bad, what) in [
        (vec![0.6, 0.5, -0.2], "negative radius"),
        (vec![0.6, f64::NAN, 0.2], "NaN centre"),
        (vec![0.6, 0.5], "two values"),
    ] {
        let tape = Tape::<f64>::new();
        let state = FlowVars::constants(&tape, &s0);
        let params = ParamVars::constants(&tape, &p);
        let body = tape.var(Array1::from(bad).into_dyn());
        let r = scene.step_with_body(&tape, &state, &params, body);
        assert!(
            matches!(
                r,
                Err(FlowError::InvalidParameter { .. }
                    | FlowError::NonFinite { .. }
                    | FlowError::Shape { .. })
            ),
            "{what}: {:?}",
            r.err()
        );
    }
    // a body on a scene without one
    let plain = common::channel().build().unwrap();
    let tape = Tape::<f64>::new();
    let state = FlowVars::constants(&tape, &FlowState::zeros(&plain));
    let params = ParamVars::constants(&tape, &plain.params());
    let body = tape.var(arr1(&shape()).into_dyn());
    let r = plain.step_with_body(&tape, &state, &params, body);
    assert!(matches!(r, Err(FlowError::InvalidParameter { .. })));
    // the op on the wrong velocity shape
    let op = ImmersedForcing::new(Arc::clone(scene.immersed().unwrap()));
    let tape = Tape::<f64>::new();
    let a = tape.var(ArrayD::zeros(ndarray::IxDyn(&[3, 3])));
    let s = tape.constant(arr1(&shape()).into_dyn());
    assert!(tape.apply_multi(op, &[a, a, s]).is_err());
}

/// A checkpointed rollout recomputes its steps in the backward sweep; its
/// [`diffphys_flow::StepLog`] keeps one report per step, so the summed force
/// and pressure iterations equal those of the plain forward steps.
#[test]
fn a_recomputed_step_is_logged_once() {
    let scene = scene_with(shape(), Interior::Forced);
    let (ux, uy) = common::velocity(&scene, 0.3, 61);
    let s0 = FlowState::from_velocity(&scene, ux, uy);
    let p = scene.params::<f64>();
    let steps = 6;
    let mut plain = [0.0; 2];
    let mut s = s0.clone();
    for _ in 0..steps {
        let (next, info) = scene.forward(&s, &p).unwrap();
        (0..2).for_each(|d| plain[d] += scene.dt() * info.immersed_force[d]);
        s = next;
    }
    for schedule in [
        Schedule::Full,
        Schedule::Every(2),
        Schedule::Nested { branches: 2 },
    ] {
        let tape = Tape::<f64>::new();
        let state = FlowVars::variables(&tape, &s0);
        let params = ParamVars::constants(&tape, &p);
        let (out, log) = scene
            .rollout_logged(&tape, schedule, steps, &state, &params)
            .unwrap();
        let loss = out.ux.dot(out.ux).unwrap();
        tape.backward(loss, &[state.ux]).unwrap();
        assert_eq!(log.len(), steps, "{schedule:?}");
        assert_eq!(log.pressure_iterations().len(), steps, "{schedule:?}");
        let logged = log.immersed_impulse(scene.dt());
        for d in 0..2 {
            assert!(
                (logged[d] - plain[d]).abs() <= 1e-12 * plain[d].abs().max(1e-12),
                "{schedule:?}: {logged:?} vs {plain:?}"
            );
        }
    }
}
