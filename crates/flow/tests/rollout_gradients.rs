//! Gradients through 20 steps of a channel with a cylinder and a moving top
//! wall, w.r.t. the initial velocity, the inflow profile, the viscosity and
//! the wall speed, against central finite differences (f64): each a
//! directional derivative along a fixed pseudo-random direction.

mod common;

use common::velocity;
use diffphys_flow::{
    Advection, Boundary, FlowParams, FlowState, FlowVars, Obstacle, ParamVars, Scene, Sides,
    ViscosityMode,
};
use diffphys_tape::{test_array, Schedule, Tape};
use ndarray::{Array1, Array2};

const STEPS: usize = 20;

fn scene(advection: Advection, mode: ViscosityMode) -> Scene {
    Scene::builder(12, 6, [2.0, 1.0])
        .sides(Sides {
            top: Boundary::moving_wall(0.5),
            ..Sides::channel()
        })
        .obstacle(Obstacle::cylinder([0.7, 0.5], 0.2))
        .parabolic_inflow(1.0)
        .viscosity(0.05)
        .dt(0.05)
        .advection(advection)
        .viscosity_mode(mode)
        .build()
        .unwrap()
}

/// The loss: a fixed weighting of the final velocity and pressure.
fn loss_of(s: &FlowState<f64>) -> f64 {
    let w = weights(s);
    s.ux.iter().zip(&w.0).map(|(a, b)| a * b).sum::<f64>()
        + s.uy.iter().zip(&w.1).map(|(a, b)| a * b).sum::<f64>()
        + s.pressure.iter().zip(&w.2).map(|(a, b)| a * b).sum::<f64>()
}

fn weights(s: &FlowState<f64>) -> (Array2<f64>, Array2<f64>, Array2<f64>) {
    let two = |a: &Array2<f64>, k| {
        test_array::<f64>(a.shape(), k)
            .into_dimensionality()
            .unwrap()
    };
    (
        two(&s.ux, 900),
        two(&s.uy, 901),
        two(&s.pressure, 902).mapv(|v| 0.01 * v),
    )
}

fn rollout(scene: &Scene, s0: &FlowState<f64>, p: &FlowParams<f64>) -> f64 {
    let mut s = s0.clone();
    for _ in 0..STEPS {
        s = scene.forward(&s, p).unwrap().0;
    }
    loss_of(&s)
}

struct Grads {
    ux: Array2<f64>,
    uy: Array2<f64>,
    viscosity: f64,
    wall_speed: Array1<f64>,
    inflow: Array1<f64>,
}

fn tape_gradients(
    scene: &Scene,
    s0: &FlowState<f64>,
    p: &FlowParams<f64>,
    schedule: Schedule,
) -> (f64, Grads) {
    let tape = Tape::<f64>::new();
    let state = FlowVars::variables(&tape, s0);
    let params = ParamVars::variables(&tape, p);
    let end = scene
        .rollout(&tape, schedule, STEPS, &state, &params)
        .unwrap();
    let w = weights(&end.values().unwrap());
    let c = |a: Array2<f64>| tape.constant(a.into_dyn());
    let loss = end
        .ux
        .dot(c(w.0))
        .unwrap()
        .add(end.uy.dot(c(w.1)).unwrap())
        .unwrap()
        .add(end.pressure.dot(c(w.2)).unwrap())
        .unwrap();
    let value = loss.item().unwrap();
    let g = tape
        .backward(
            loss,
            &[
                state.ux,
                state.uy,
                params.viscosity,
                params.wall_speed,
                params.inflow,
            ],
        )
        .unwrap();
    let two = |v| g.get(v).unwrap().clone().into_dimensionality().unwrap();
    (
        value,
        Grads {
            ux: two(state.ux),
            uy: two(state.uy),
            viscosity: g.get(params.viscosity).unwrap().iter().sum(),
            wall_speed: two_1(g.get(params.wall_speed).unwrap().clone()),
            inflow: two_1(g.get(params.inflow).unwrap().clone()),
        },
    )
}

fn two_1(a: diffphys_tape::ArrayD<f64>) -> Array1<f64> {
    a.into_dimensionality().unwrap()
}

/// A change of the inputs by `ε` along a direction.
type Perturb<'a> = dyn Fn(f64, &mut FlowState<f64>, &mut FlowParams<f64>) + 'a;

/// `(dL/dε (central difference), <g, v>)` along a direction that perturbs
/// one group of inputs.
fn directional(
    scene: &Scene,
    s0: &FlowState<f64>,
    p: &FlowParams<f64>,
    eps: f64,
    perturb: &Perturb<'_>,
) -> f64 {
    let (mut s_plus, mut p_plus) = (s0.clone(), p.clone());
    perturb(eps, &mut s_plus, &mut p_plus);
    let (mut s_minus, mut p_minus) = (s0.clone(), p.clone());
    perturb(-eps, &mut s_minus, &mut p_minus);
    (rollout(scene, &s_plus, &p_plus) - rollout(scene, &s_minus, &p_minus)) / (2.0 * eps)
}

fn check(advection: Advection, mode: ViscosityMode) {
    let scene = scene(advection, mode);
    let (ux, uy) = velocity(&scene, 0.3, 11);
    let s0 = FlowState::from_velocity(&scene, ux, uy);
    let p = scene.params::<f64>();
    let (value, g) = tape_gradients(&scene, &s0, &p, Schedule::Full);
    assert!((value - rollout(&scene, &s0, &p)).abs() < 1e-12 * value.abs().max(1.0));

    let (dx, dy) = velocity(&scene, 1.0, 13);
    let dinflow: Array1<f64> = test_array::<f64>(&[scene.inflow_len()], 14)
        .into_dimensionality()
        .unwrap();
    let eps = 1e-6;
    let cases: Vec<(&str, f64, f64)> = vec![
        (
            "initial velocity",
            directional(&scene, &s0, &p, eps, &|e, s, _| {
                s.ux.scaled_add(e, &dx);
                s.uy.scaled_add(e, &dy);
            }),
            (&g.ux * &dx).sum() + (&g.uy * &dy).sum(),
        ),
        (
            "inflow profile",
            directional(&scene, &s0, &p, eps, &|e, _, p| {
                p.inflow.scaled_add(e, &dinflow)
            }),
            (&g.inflow * &dinflow).sum(),
        ),
        (
            "viscosity",
            directional(&scene, &s0, &p, eps * 0.05, &|e, _, p| p.viscosity += e),
            g.viscosity,
        ),
        (
            "lid speed",
            directional(&scene, &s0, &p, eps, &|e, _, p| p.wall_speed[3] += e),
            g.wall_speed[3],
        ),
    ];
    for (what, fd, ad) in cases {
        println!("{advection:?} {mode:?} d loss / d {what}: finite differences {fd:.10e}, tape {ad:.10e}");
        assert!(
            ad.abs() > 1e-6,
            "{what}: the gradient is (nearly) zero: {ad:e}"
        );
        assert!(
            (fd - ad).abs() <= 1e-5 * fd.abs().max(1e-3),
            "{what}: fd {fd:e} vs tape {ad:e}"
        );
    }
    // walls that do not move get no gradient from the ghost they do not have
    assert_eq!(g.wall_speed[0], 0.0);
}

#[test]
fn gradients_through_20_steps_match_finite_differences() {
    check(Advection::SemiLagrangian, ViscosityMode::Explicit);
}

#[test]
fn gradients_through_20_maccormack_steps_with_implicit_viscosity() {
    check(
        Advection::MacCormack { limiter: false },
        ViscosityMode::Implicit,
    );
}

#[test]
fn checkpointed_rollout_gives_the_full_tape_gradient() {
    let scene = scene(Advection::SemiLagrangian, ViscosityMode::Explicit);
    let (ux, uy) = velocity(&scene, 0.3, 21);
    let s0 = FlowState::from_velocity(&scene, ux, uy);
    let p = scene.params::<f64>();
    let (v_full, g_full) = tape_gradients(&scene, &s0, &p, Schedule::Full);
    let (v_ck, g_ck) = tape_gradients(&scene, &s0, &p, Schedule::Every(5));
    assert_eq!(v_full, v_ck);
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(1.0);
    assert!(g_full.ux.iter().zip(&g_ck.ux).all(|(a, b)| close(*a, *b)));
    assert!(g_full
        .inflow
        .iter()
        .zip(&g_ck.inflow)
        .all(|(a, b)| close(*a, *b)));
    assert!(close(g_full.viscosity, g_ck.viscosity));
}
