//! Bad input is a typed error naming the step and the quantity, never a panic
//! or a NaN handed on: one test each.

mod common;

use diffphys_flow::{
    Boundary, FlowError, FlowState, FlowVars, Obstacle, ParamVars, PressureSolver, Scene, Sides,
};
use diffphys_tape::Tape;
use ndarray::Array1;

#[test]
fn obstacle_covering_the_inflow_side() {
    let e = common::channel()
        .obstacle(Obstacle::rectangle([0.0, 0.2], [0.5, 0.8]))
        .build()
        .unwrap_err();
    assert!(
        matches!(&e, FlowError::InvalidScene { what, message } if what == "obstacle" && message.contains("inflow")),
        "{e}"
    );
}

#[test]
fn viscosity_not_positive() {
    let e = common::cavity().viscosity(0.0).build().unwrap_err();
    assert!(
        matches!(&e, FlowError::InvalidScene { what, .. } if what == "viscosity"),
        "{e}"
    );
    // and as a parameter of a step
    let scene = common::cavity().build().unwrap();
    let mut p = scene.params::<f64>();
    p.viscosity = -1e-3;
    let e = scene.forward(&FlowState::zeros(&scene), &p).unwrap_err();
    assert!(
        matches!(&e, FlowError::InvalidParameter { step, quantity, .. } if step == "flow step" && quantity == "viscosity"),
        "{e}"
    );
}

#[test]
fn grid_too_small_for_the_obstacle() {
    // a cylinder of diameter 0.1 on cells of 1/6
    let e = common::channel()
        .obstacle(Obstacle::cylinder([1.0, 0.5], 0.05))
        .build()
        .unwrap_err();
    assert!(
        matches!(&e, FlowError::InvalidScene { what, message } if what == "obstacle" && message.contains("too small")),
        "{e}"
    );
}

#[test]
fn nan_in_the_state() {
    let scene = common::channel().build().unwrap();
    let mut s = FlowState::zeros(&scene);
    s.uy[[3, 2]] = f64::NAN;
    let e = scene.forward(&s, &scene.params()).unwrap_err();
    assert!(
        matches!(&e, FlowError::NonFinite { step, quantity, count: 1 } if step == "flow step" && quantity == "y-velocity"),
        "{e}"
    );
}

#[test]
fn cfl_violation_and_substepping() {
    let scene = common::cavity().dt(0.5).build().unwrap();
    let e = scene
        .forward(&FlowState::<f64>::zeros(&scene), &scene.params())
        .unwrap_err();
    // the lid is not in the state; ν dt (1/h² + 1/h²) = 0.05·0.5·72 = 1.8 > ½
    assert!(
        matches!(&e, FlowError::Cfl { step, quantity, .. } if step == "explicit diffusion" && quantity == "diffusion"),
        "{e}"
    );
    let scene = common::periodic().dt(0.2).build().unwrap();
    let (ux, uy) = common::velocity(&scene, 1.0, 1);
    let s = FlowState::from_velocity(&scene, ux, uy);
    let e = scene.forward(&s, &scene.params()).unwrap_err();
    assert!(
        matches!(&e, FlowError::Cfl { step, quantity, number, limit } if step == "advection" && quantity == "Courant" && number > limit),
        "{e}"
    );
    // with substepping the step picks and reports the count
    let scene = common::periodic()
        .dt(0.2)
        .substepping(true)
        .build()
        .unwrap();
    let (_, info) = scene.forward(&s, &scene.params()).unwrap();
    assert!(
        info.substeps > 1 && info.courant / info.substeps as f64 <= 1.0,
        "{info:?}"
    );
}

#[test]
fn unconverged_pressure_solve() {
    let scene = common::channel()
        .pressure_solver(PressureSolver::Cg {
            rel_tol: 1e-12,
            max_iters: 2,
        })
        .build()
        .unwrap();
    let (ux, uy) = common::velocity(&scene, 0.5, 2);
    let s = FlowState::from_velocity(&scene, ux, uy);
    let e = scene.forward(&s, &scene.params()).unwrap_err();
    assert!(
        matches!(&e, FlowError::Solve { step, quantity, .. } if step == "pressure solve" && quantity == "pressure"),
        "{e}"
    );
    // the same through the tape
    let tape = Tape::<f64>::new();
    let e = scene
        .step(
            &tape,
            &FlowVars::variables(&tape, &s),
            &ParamVars::variables(&tape, &scene.params()),
        )
        .unwrap_err();
    assert!(
        matches!(&e, FlowError::Solve { step, .. } if step == "pressure solve"),
        "{e}"
    );
}

#[test]
fn state_of_the_wrong_shape() {
    let scene = common::cavity().build().unwrap();
    let mut s = FlowState::<f64>::zeros(&scene);
    s.ux = ndarray::Array2::zeros((6, 6)); // needs 7 × 6
    let e = scene.forward(&s, &scene.params()).unwrap_err();
    assert!(
        matches!(&e, FlowError::Shape { step, quantity, expected, found } if step == "flow step" && quantity == "x-velocity" && expected == &[7, 6] && found == &[6, 6]),
        "{e}"
    );
}

#[test]
fn inflow_profile_of_the_wrong_length() {
    let e = common::channel().inflow(vec![1.0; 5]).build().unwrap_err();
    assert!(
        matches!(&e, FlowError::InvalidScene { what, .. } if what == "inflow profile"),
        "{e}"
    );
    let scene = common::channel().build().unwrap();
    let mut p = scene.params::<f64>();
    p.inflow = Array1::ones(7);
    let e = scene.forward(&FlowState::zeros(&scene), &p).unwrap_err();
    assert!(
        matches!(&e, FlowError::Shape { step, quantity, .. } if step == "flow step" && quantity == "inflow profile"),
        "{e}"
    );
}

#[test]
fn one_periodic_side_alone() {
    let e = Scene::builder(4, 4, [1.0, 1.0])
        .sides(Sides {
            left: Boundary::periodic(),
            ..Sides::all(Boundary::no_slip())
        })
        .build()
        .unwrap_err();
    assert!(
        matches!(&e, FlowError::InvalidScene { what, .. } if what == "sides"),
        "{e}"
    );
}
