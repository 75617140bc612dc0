//! The projection leaves no divergence (f64), with and without the obstacle,
//! for every pressure solver; the warm start changes the iterations, not the
//! answer.

mod common;

use common::{scenes, velocity};
use diffphys_flow::boundaries::enforce_boundaries;
use diffphys_flow::diagnostics::max_divergence;
use diffphys_flow::pressure::project;
use diffphys_flow::{FlowState, PressureSolver, Scene};
use ndarray::Array1;

fn solvers() -> Vec<PressureSolver> {
    vec![
        PressureSolver::Cholesky,
        PressureSolver::Cg {
            rel_tol: 1e-13,
            max_iters: 2000,
        },
        PressureSolver::MultigridCg {
            rel_tol: 1e-13,
            max_iters: 200,
            sweeps: 2,
        },
    ]
}

#[test]
fn divergence_after_projection_is_below_1e_8() {
    for solver in solvers() {
        for (name, b) in scenes() {
            let scene = b.pressure_solver(solver.clone()).build().unwrap();
            let has_obstacle = scene.solid().iter().any(|&s| s);
            let (ux, uy) = velocity(&scene, 1.0, 3);
            let inflow: Array1<f64> = scene.params::<f64>().inflow;
            let (ux, uy) = enforce_boundaries(
                scene.grid(),
                scene.faces(),
                ux.view(),
                uy.view(),
                inflow.view(),
            )
            .unwrap();
            let before = max_divergence(scene.grid(), scene.solid(), ux.view(), uy.view()).unwrap();
            let out = project(
                scene.pressure_system(),
                scene.dt(),
                ux.view(),
                uy.view(),
                None,
            )
            .unwrap();
            let after =
                max_divergence(scene.grid(), scene.solid(), out.ux.view(), out.uy.view()).unwrap();
            println!("{name:9} obstacle {has_obstacle:5} {solver:?}: max |div u| {before:.3e} -> {after:.3e} ({} iterations)", out.iterations);
            assert!(before > 1e-2, "{name}: the test field should be divergent");
            assert!(after <= 1e-8, "{name} {solver:?}: max |div u'| = {after:e}");
        }
    }
}

#[test]
fn a_step_keeps_the_flow_divergence_free_with_the_obstacle() {
    for (name, b) in scenes() {
        let scene: Scene = b.build().unwrap();
        let (ux, uy) = velocity(&scene, 0.5, 5);
        let mut s = FlowState::from_velocity(&scene, ux, uy);
        let p = scene.params::<f64>();
        for _ in 0..3 {
            s = scene.forward(&s, &p).unwrap().0;
        }
        let d = max_divergence(scene.grid(), scene.solid(), s.ux.view(), s.uy.view()).unwrap();
        assert!(d <= 1e-8, "{name}: {d:e}");
    }
}

#[test]
fn warm_start_saves_iterations_and_keeps_the_answer() {
    let scene = common::channel()
        .pressure_solver(PressureSolver::Cg {
            rel_tol: 1e-10,
            max_iters: 5000,
        })
        .build()
        .unwrap();
    let (ux, uy) = velocity(&scene, 1.0, 7);
    let inflow = scene.params::<f64>().inflow;
    let (ux, uy) = enforce_boundaries(
        scene.grid(),
        scene.faces(),
        ux.view(),
        uy.view(),
        inflow.view(),
    )
    .unwrap();
    let cold = project(
        scene.pressure_system(),
        scene.dt(),
        ux.view(),
        uy.view(),
        None,
    )
    .unwrap();
    let warm = project(
        scene.pressure_system(),
        scene.dt(),
        ux.view(),
        uy.view(),
        Some(cold.pressure.view()),
    )
    .unwrap();
    assert!(
        warm.iterations < cold.iterations,
        "{} vs {}",
        warm.iterations,
        cold.iterations
    );
    let diff = (&warm.ux - &cold.ux)
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(diff < 1e-8, "{diff:e}");
}

/// The flow and diffphys-ops share one staggered layout: the velocity arrays
/// of a scene go unchanged into ops' projection on [`FlowGrid::mac`], which
/// gives the flow's projected velocity (walls and inflow at rest, so that the
/// closed faces carry no flow in either).
#[test]
fn ops_projection_takes_the_flow_arrays() {
    use diffphys_ops::cg::CgParams;
    use diffphys_ops::projection::PressureProjection;
    for (name, b) in scenes() {
        let scene = b.pressure_solver(PressureSolver::Cholesky).build().unwrap();
        let (ux, uy) = velocity(&scene, 1.0, 5);
        let at_rest = Array1::<f64>::zeros(scene.params::<f64>().inflow.len());
        let (ux, uy) = enforce_boundaries(
            scene.grid(),
            scene.faces(),
            ux.view(),
            uy.view(),
            at_rest.view(),
        )
        .unwrap();
        let flow = project(scene.pressure_system(), 1.0, ux.view(), uy.view(), None).unwrap();
        let mac = scene.grid().mac(Some(scene.solid())).unwrap();
        assert_eq!(mac.shape_x(), scene.grid().shape_x(), "{name}");
        assert_eq!(mac.shape_y(), scene.grid().shape_y(), "{name}");
        let ops = PressureProjection::new(mac, CgParams::default().with_rel_tol(1e-13))
            .project(ux.view().into_dyn(), uy.view().into_dyn(), None)
            .unwrap();
        let diff = |a: &ndarray::Array2<f64>, b: &ndarray::ArrayD<f64>| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max)
        };
        let scale = ux.iter().chain(&uy).fold(0.0_f64, |m, v| m.max(v.abs()));
        let (dx, dy) = (
            diff(&flow.ux, &ops.velocity_x),
            diff(&flow.uy, &ops.velocity_y),
        );
        println!("{name:9}: max |u'_flow − u'_ops| = {dx:.2e}, {dy:.2e} (max |u| {scale:.2})");
        assert!(dx.max(dy) <= 1e-9 * scale, "{name}: {dx:e}, {dy:e}");
    }
}
