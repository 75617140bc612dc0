//! The force on a staircase body as the step's momentum balance sees it
//! (`ForceWeights::momentum_exchange`): on a periodic box with an obstacle,
//! where no side brings momentum in, what one explicit viscosity step and one
//! projection take out of the fluid is the force those weights give, to
//! rounding; the force's adjoint passes the dot-product test; and the drag it
//! gives after a few steps of a channel flow has the tape's gradient with
//! respect to the initial velocity, the inflow and the viscosity that central
//! differences give.

mod common;

use diffphys_flow::boundaries::enforce_boundaries;
use std::sync::Arc;

use diffphys_flow::diagnostics::{obstacle_force, obstacle_force_vjp, ForceWeights, ObstacleForce};
use diffphys_flow::diffusion::diffuse;
use diffphys_flow::pressure::project;
use diffphys_flow::{
    FlowParams, FlowState, FlowVars, Obstacle, ParamVars, Scene, Sides, ViscosityMode,
};
use diffphys_tape::{test_array, Schedule, Tape};
use ndarray::{Array1, Array2};

const NU: f64 = 0.02;
const DT: f64 = 0.01;

/// A periodic 16 × 12 box with an off-centre cylinder, and a velocity with
/// its obstacle faces set to zero.
fn periodic_body() -> (Scene, Array2<f64>, Array2<f64>) {
    let scene = Scene::builder(16, 12, [1.6, 1.0])
        .sides(Sides::periodic())
        .obstacle(Obstacle::cylinder([0.62, 0.47], 0.23))
        .viscosity(NU)
        .dt(DT)
        .build()
        .unwrap();
    let (ux, uy) = common::velocity(&scene, 1.0, 7);
    let (ux, uy) = enforce_boundaries(
        scene.grid(),
        scene.faces(),
        ux.view(),
        uy.view(),
        Array1::<f64>::zeros(0).view(),
    )
    .unwrap();
    (scene, ux, uy)
}

/// `Σ (after − before) dx dy / t` per component: the momentum gained per
/// unit time.
fn gained(scene: &Scene, before: [&Array2<f64>; 2], after: [&Array2<f64>; 2], t: f64) -> [f64; 2] {
    let g = scene.grid();
    [0, 1].map(|d| {
        after[d]
            .iter()
            .zip(before[d].iter())
            .map(|(a, b)| a - b)
            .sum::<f64>()
            * g.dx
            * g.dy
            / t
    })
}

#[test]
fn one_viscosity_step_takes_the_exchange_force_out_of_the_fluid() {
    let (scene, ux, uy) = periodic_body();
    let weights = ForceWeights::momentum_exchange(scene.grid(), scene.solid());
    let (vx, vy) = diffuse(
        scene.diffusion(),
        ViscosityMode::Explicit,
        DT,
        ux.view(),
        uy.view(),
        NU,
        Array1::<f64>::zeros(4).view(),
    )
    .unwrap();
    let gain = gained(&scene, [&ux, &uy], [&vx, &vy], DT);
    let zero_p = Array2::<f64>::zeros(scene.solid().dim());
    let f = obstacle_force(&weights, ux.view(), uy.view(), zero_p.view(), NU).unwrap();
    for d in 0..2 {
        // the fluid loses what the body gains
        assert!(
            (gain[d] + f[d]).abs() <= 1e-12 * f[d].abs().max(1.0),
            "component {d}: momentum gained {} against the force {}",
            gain[d],
            f[d]
        );
    }
    // the continuous-wall shear of ForceWeights::new is another number
    let wall = obstacle_force(
        scene.force_weights(),
        ux.view(),
        uy.view(),
        zero_p.view(),
        NU,
    )
    .unwrap();
    assert!((wall[0] - f[0]).abs() > 1e-3 * f[0].abs(), "{wall:?} {f:?}");
}

#[test]
fn one_projection_takes_the_pressure_force_out_of_the_fluid() {
    let (scene, ux, uy) = periodic_body();
    let weights = ForceWeights::momentum_exchange(scene.grid(), scene.solid());
    let tau = 0.5;
    let p = project(scene.pressure_system(), tau, ux.view(), uy.view(), None).unwrap();
    let gain = gained(&scene, [&ux, &uy], [&p.ux, &p.uy], tau);
    // the pressure part alone: ν = 0
    let f = obstacle_force(&weights, ux.view(), uy.view(), p.pressure.view(), 0.0).unwrap();
    for d in 0..2 {
        assert!(
            (gain[d] + f[d]).abs() <= 1e-10 * f[d].abs().max(1.0),
            "component {d}: momentum gained {} against the pressure force {}",
            gain[d],
            f[d]
        );
    }
}

#[test]
fn the_exchange_force_passes_the_dot_product_test() {
    let (scene, ux, uy) = periodic_body();
    let weights = ForceWeights::momentum_exchange(scene.grid(), scene.solid());
    let p: Array2<f64> = test_array::<f64>(&[16, 12], 11)
        .into_dimensionality()
        .unwrap();
    let g = [0.3, -1.7];
    let f = obstacle_force(&weights, ux.view(), uy.view(), p.view(), NU).unwrap();
    let r = obstacle_force_vjp(&weights, ux.view(), uy.view(), NU, g).unwrap();
    // F is linear in (u, P) at fixed ν: <F, g> = <u, Jᵀg> + <P, Jᵀg>
    let lhs = f[0] * g[0] + f[1] * g[1];
    let dot = |a: &Array2<f64>, b: &Array2<f64>| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let rhs = dot(&ux, &r.ux) + dot(&uy, &r.uy) + dot(&p, &r.pressure);
    assert!(
        (lhs - rhs).abs() <= 1e-12 * lhs.abs().max(1.0),
        "{lhs} {rhs}"
    );
    // and ∂F/∂ν: the viscous part over ν
    let f0 = obstacle_force(&weights, ux.view(), uy.view(), p.view(), 0.0).unwrap();
    let dnu = ((f[0] - f0[0]) * g[0] + (f[1] - f0[1]) * g[1]) / NU;
    assert!((r.viscosity - dnu).abs() <= 1e-12 * dnu.abs().max(1.0));
}

const STEPS: usize = 5;

/// A change of the inputs by `ε` along a direction.
type Perturb<'a> = dyn Fn(f64, &mut FlowState<f64>, &mut FlowParams<f64>) + 'a;

/// The drag by the momentum exchange after [`STEPS`] steps of the tests'
/// channel (12 × 6, a cylinder, parabolic inflow).
fn drag_after_steps(
    scene: &Scene,
    w: &ForceWeights,
    s0: &FlowState<f64>,
    p: &FlowParams<f64>,
) -> f64 {
    let mut s = s0.clone();
    for _ in 0..STEPS {
        s = scene.forward(&s, p).unwrap().0;
    }
    obstacle_force(w, s.ux.view(), s.uy.view(), s.pressure.view(), p.viscosity).unwrap()[0]
}

#[test]
fn the_exchange_drag_through_five_steps_has_the_finite_difference_gradient() {
    let scene = common::channel().build().unwrap();
    let weights = Arc::new(ForceWeights::momentum_exchange(scene.grid(), scene.solid()));
    let (ux, uy) = common::velocity(&scene, 0.3, 21);
    let s0 = FlowState::from_velocity(&scene, ux, uy);
    let p = scene.params::<f64>();

    let tape = Tape::<f64>::new();
    let state = FlowVars::variables(&tape, &s0);
    let params = ParamVars::variables(&tape, &p);
    let end = scene
        .rollout(&tape, Schedule::Full, STEPS, &state, &params)
        .unwrap();
    let force = tape
        .apply(
            ObstacleForce {
                weights: Arc::clone(&weights),
            },
            &[end.ux, end.uy, end.pressure, params.viscosity],
        )
        .unwrap();
    let pick = tape.constant(ndarray::arr1(&[1.0, 0.0]).into_dyn());
    let drag = force.dot(pick).unwrap();
    let value = drag.item().unwrap();
    assert!((value - drag_after_steps(&scene, &weights, &s0, &p)).abs() < 1e-12 * value.abs());
    let g = tape
        .backward(drag, &[state.ux, state.uy, params.inflow, params.viscosity])
        .unwrap();

    let (dx, dy) = common::velocity(&scene, 1.0, 23);
    let dinflow: Array1<f64> = test_array::<f64>(&[scene.inflow_len()], 24)
        .into_dimensionality()
        .unwrap();
    let along = |eps: f64, f: &Perturb<'_>| {
        let run = |e: f64| {
            let (mut s, mut q) = (s0.clone(), p.clone());
            f(e, &mut s, &mut q);
            drag_after_steps(&scene, &weights, &s, &q)
        };
        (run(eps) - run(-eps)) / (2.0 * eps)
    };
    let dot = |a: &diffphys_tape::ArrayD<f64>, b: &[f64]| {
        a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>()
    };
    let cases = [
        (
            "initial velocity",
            along(1e-6, &|e, s, _| {
                s.ux.scaled_add(e, &dx);
                s.uy.scaled_add(e, &dy);
            }),
            dot(g.get(state.ux).unwrap(), dx.as_slice().unwrap())
                + dot(g.get(state.uy).unwrap(), dy.as_slice().unwrap()),
        ),
        (
            "inflow profile",
            along(1e-6, &|e, _, q| q.inflow.scaled_add(e, &dinflow)),
            dot(g.get(params.inflow).unwrap(), dinflow.as_slice().unwrap()),
        ),
        (
            "viscosity",
            along(5e-8, &|e, _, q| q.viscosity += e),
            g.get(params.viscosity).unwrap().iter().sum(),
        ),
    ];
    for (what, fd, ad) in cases {
        println!("d drag / d {what}: finite differences {fd:.10e}, tape {ad:.10e}");
        assert!(
            ad.abs() > 1e-6,
            "{what}: the gradient is (nearly) zero: {ad:e}"
        );
        assert!(
            (fd - ad).abs() <= 1e-5 * fd.abs().max(1e-3),
            "{what}: fd {fd:e} vs tape {ad:e}"
        );
    }
}
