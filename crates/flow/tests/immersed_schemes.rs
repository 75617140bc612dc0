//! The immersed circle's other forcing schemes (`ForcingScheme::Consistent`,
//! `ForcingScheme::MultiDirect`): each is linear at a fixed circle and its
//! adjoint passes the dot-product test, its shape gradient matches central
//! differences, and one multi-direct pass is the direct step to the bit.

mod common;

use common::immersed::{dot, scene_scheme, shape, CENTRE, RADIUS};
use diffphys_flow::immersed::{
    consistent_forcing, consistent_forcing_vjp, immersed_forcing, multi_direct_forcing,
    multi_direct_forcing_vjp,
};
use diffphys_flow::pressure::project;
use diffphys_flow::{Circle, FlowError, FlowState, ForcingScheme, Interior, Scene, Sides};
use diffphys_tape::test_array;
use ndarray::{arr1, Array1, Array2};

/// The consistent forcing `u' = F(u − τ G P) + τ (1 − Z) G P` is linear in
/// `(u, P)` at a fixed circle: `<A (u, P), g> = <u, A_uᵀ g> + <P, A_Pᵀ g>`;
/// at `P = 0` it is the direct forcing; its shape gradient matches central
/// differences.
#[test]
fn the_consistent_forcing_passes_the_dot_product_test() {
    let tau = 0.013;
    for interior in [Interior::Solid, Interior::Forced, Interior::Closed] {
        let scene = scene_scheme(shape(), interior, ForcingScheme::ProjectionConsistent);
        let (body, faces) = (scene.immersed().unwrap(), scene.faces());
        let s = arr1(&shape());
        let (ux, uy) = common::velocity(&scene, 1.0, 51);
        let (gx, gy) = common::velocity(&scene, 1.0, 53);
        let p: Array2<f64> = test_array::<f64>(&scene.grid().cell_shape(), 55)
            .into_dimensionality()
            .unwrap();
        let run = |p: &Array2<f64>, s: &Array1<f64>| {
            consistent_forcing(body, faces, tau, (ux.view(), uy.view()), p.view(), s.view())
                .unwrap()
        };
        let (ax, ay) = run(&p, &s);
        let (jx, jy, jp, js) = consistent_forcing_vjp(
            body,
            faces,
            tau,
            (ux.view(), uy.view()),
            p.view(),
            s.view(),
            (gx.view(), gy.view()),
        )
        .unwrap();
        let lhs = dot(&ax, &gx) + dot(&ay, &gy);
        let rhs = dot(&ux, &jx) + dot(&uy, &jy) + dot(&p, &jp);
        assert!(
            (lhs - rhs).abs() <= 1e-12 * lhs.abs().max(1.0),
            "{interior:?}: {lhs} {rhs}"
        );
        // the pressure enters: its gradient is not zero
        assert!(jp.iter().any(|v| v.abs() > 1e-6));
        // P = 0: the direct forcing, to the bit
        let zero = Array2::zeros(p.raw_dim());
        let direct = immersed_forcing(body, ux.view(), uy.view(), s.view()).unwrap();
        assert_eq!(run(&zero, &s), direct);
        // ∂L/∂shape against central differences
        for k in 0..3 {
            let eps = 1e-6;
            let (mut up, mut down) = (s.clone(), s.clone());
            up[k] += eps;
            down[k] -= eps;
            let loss = |s: &Array1<f64>| {
                let (a, b) = run(&p, s);
                dot(&a, &gx) + dot(&b, &gy)
            };
            let fd = (loss(&up) - loss(&down)) / (2.0 * eps);
            assert!(
                (fd - js[k]).abs() <= 1e-7 * fd.abs().max(1.0),
                "{interior:?}, shape {k}: fd {fd} vs vjp {}",
                js[k]
            );
        }
    }
}

/// The multi-direct forcing (`K` passes of forcing and projection) is linear
/// in the velocity: its adjoint passes the dot-product test in `(u', P)`, its
/// shape gradient matches central differences, one pass is the direct
/// forcing followed by the projection to the bit, and the passes shrink the
/// slip `max |u' − F(u')|` on the forced faces.
#[test]
fn the_multi_direct_forcing_passes_the_dot_product_test() {
    let tau = 0.013;
    for interior in [Interior::Solid, Interior::Forced, Interior::Closed] {
        let scene = scene_scheme(shape(), interior, ForcingScheme::MultiDirect { passes: 3 });
        let (body, system) = (scene.immersed().unwrap(), scene.pressure_system());
        let s = arr1(&shape());
        let (ux, uy) = common::velocity(&scene, 1.0, 61);
        let (gx, gy) = common::velocity(&scene, 1.0, 63);
        let gp: Array2<f64> = test_array::<f64>(&scene.grid().cell_shape(), 65)
            .into_dimensionality()
            .unwrap();
        let run = |passes: usize, s: &Array1<f64>| {
            multi_direct_forcing(
                body,
                system,
                tau,
                passes,
                (ux.view(), uy.view()),
                None,
                s.view(),
            )
            .unwrap()
        };
        let out = run(3, &s);
        let (jx, jy, js) = multi_direct_forcing_vjp(
            body,
            system,
            tau,
            3,
            (ux.view(), uy.view()),
            s.view(),
            (gx.view(), gy.view()),
            Some(gp.view()),
        )
        .unwrap();
        // <J u, (g_u, g_P)> = <u, Jᵀ (g_u, g_P)> at a fixed circle
        let lhs = dot(&out.ux, &gx) + dot(&out.uy, &gy) + dot(&out.pressure, &gp);
        let rhs = dot(&ux, &jx) + dot(&uy, &jy);
        assert!(
            (lhs - rhs).abs() <= 1e-12 * lhs.abs().max(1.0),
            "{interior:?}: {lhs} {rhs}"
        );
        // one pass: the direct forcing, then the projection, to the bit
        let (fx, fy) = immersed_forcing(body, ux.view(), uy.view(), s.view()).unwrap();
        let one = project(system, tau, fx.view(), fy.view(), None).unwrap();
        let single = run(1, &s);
        assert_eq!(
            (&single.ux, &single.uy, &single.pressure),
            (&one.ux, &one.uy, &one.pressure)
        );
        // the slip left on the forced faces falls with the passes
        let (mx, my) = body.forced_mask();
        let slip = |o: &diffphys_flow::immersed::MultiDirect<f64>| {
            let (tx, ty) = immersed_forcing(body, o.ux.view(), o.uy.view(), s.view()).unwrap();
            [(&mx, &o.ux, &tx), (&my, &o.uy, &ty)]
                .iter()
                .flat_map(|(m, u, t)| {
                    m.iter()
                        .zip(u.iter().zip(t.iter()))
                        .filter(|(m, _)| **m == 1.0)
                        .map(|(_, (u, t))| (u - t).abs())
                        .collect::<Vec<_>>()
                })
                .fold(0.0f64, f64::max)
        };
        let slips = [slip(&single), slip(&out), slip(&run(8, &s))];
        println!("{interior:?}: slip after 1, 3, 8 passes {slips:?}");
        assert!(slips[1] < slips[0] && slips[2] < slips[1], "{slips:?}");
        // ∂L/∂shape against central differences
        for k in 0..3 {
            let eps = 1e-6;
            let (mut up, mut down) = (s.clone(), s.clone());
            up[k] += eps;
            down[k] -= eps;
            let loss = |s: &Array1<f64>| {
                let o = run(3, s);
                dot(&o.ux, &gx) + dot(&o.uy, &gy) + dot(&o.pressure, &gp)
            };
            let fd = (loss(&up) - loss(&down)) / (2.0 * eps);
            assert!(js[k].abs() > 1e-4, "{interior:?}, shape {k}: {}", js[k]);
            assert!(
                (fd - js[k]).abs() <= 1e-7 * fd.abs().max(1.0),
                "{interior:?}, shape {k}: fd {fd} vs vjp {}",
                js[k]
            );
        }
    }
}

/// [`ForcingScheme::MultiDirect`] with one pass is the direct scheme's step,
/// to the bit; no pass is a typed error.
#[test]
fn one_multi_direct_pass_is_the_direct_step() {
    for interior in [Interior::Solid, Interior::Forced] {
        let direct = scene_scheme(shape(), interior, ForcingScheme::Direct);
        let one = scene_scheme(shape(), interior, ForcingScheme::MultiDirect { passes: 1 });
        let (ux, uy) = common::velocity(&direct, 0.3, 71);
        let s0 = FlowState::from_velocity(&direct, ux, uy);
        let (a, ia) = direct.forward(&s0, &direct.params()).unwrap();
        let (b, ib) = one.forward(&a, &one.params()).unwrap();
        let (c, ic) = direct.forward(&a, &direct.params()).unwrap();
        assert_eq!((&b.ux, &b.uy, &b.pressure), (&c.ux, &c.uy, &c.pressure));
        assert_eq!(ib.immersed_force, ic.immersed_force);
        assert_ne!(ia.immersed_force, [0.0; 2]);
        // three passes: three solves, and a different step
        let three = scene_scheme(shape(), interior, ForcingScheme::MultiDirect { passes: 3 });
        let (d, id) = three.forward(&a, &three.params()).unwrap();
        assert_eq!(id.pressure_iterations.len(), 3);
        assert_ne!(d.ux, c.ux);
    }
    let err = Scene::builder(24, 12, [2.0, 1.0])
        .sides(Sides::channel())
        .immersed(Circle::new(CENTRE, RADIUS).unwrap())
        .immersed_scheme(ForcingScheme::MultiDirect { passes: 0 })
        .parabolic_inflow(1.0)
        .build();
    assert!(
        matches!(err, Err(FlowError::InvalidScene { .. })),
        "{err:?}"
    );
}
