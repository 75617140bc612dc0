//! Boundary conditions are an extension point: a Navier slip wall defined
//! here, outside crates/flow, joins the step as a type implementing
//! `SideCondition`, without editing the crate. Its limits are the shipped
//! walls to the bit, a channel driven by a body force between two such walls
//! reaches the analytic slip-Poiseuille profile, the gradient of a loss
//! through several steps matches central finite differences, and a condition
//! whose answers do not fit together is refused with a typed error.

use std::sync::Arc;

use diffphys::flow::sides::{FreeSlip, Ghost, NoSlip, NormalVelocity, PressureSide};
use diffphys::flow::{
    Boundary, FlowError, FlowGrid, FlowParams, FlowState, FlowVars, Forcing, ParamVars, Scene,
    SideCondition, Sides,
};
use diffphys::tape::{check_gradient, test_array, ArrayD, GradCheckOptions, Tape, Var};
use ndarray::{Array2, ArrayView2};

/// A wall with zero normal velocity where the tangential velocity slips in
/// proportion to its shear: `u_w = λ ∂u/∂n`. With the wall value the mean of
/// the ghost and the inner value and the shear their difference over `h`,
/// the ghost is `u_g = (2λ − h) / (2λ + h) · u_i`: `−u_i` (no slip) at
/// `λ = 0`, `u_i` (free slip) as `λ → ∞`.
#[derive(Debug, Clone, PartialEq)]
struct NavierSlip {
    slip_length: f64,
}

impl SideCondition for NavierSlip {
    fn name(&self) -> String {
        format!("navier_slip({})", self.slip_length)
    }

    fn normal(&self) -> NormalVelocity {
        NormalVelocity::Zero
    }

    fn ghost(&self, h: f64) -> Ghost {
        let l = 2.0 * self.slip_length;
        Ghost {
            factor: (l - h) / (l + h),
            wall: 0.0,
        }
    }

    fn pressure(&self) -> PressureSide {
        PressureSide::Closed
    }
}

/// A side that claims a free normal velocity but a closed pressure: the
/// projection could not hold both.
#[derive(Debug, Clone, PartialEq)]
struct Inconsistent;

impl SideCondition for Inconsistent {
    fn name(&self) -> String {
        "inconsistent".into()
    }
    fn normal(&self) -> NormalVelocity {
        NormalVelocity::Free
    }
    fn ghost(&self, _: f64) -> Ghost {
        Ghost {
            factor: 1.0,
            wall: 0.0,
        }
    }
    fn pressure(&self) -> PressureSide {
        PressureSide::Closed
    }
}

/// A uniform body force `G` along x: `Δu_x = dt G`, constant, so its
/// vector–Jacobian product is zero.
#[derive(Debug)]
struct BodyForce(f64);

impl Forcing for BodyForce {
    fn name(&self) -> &str {
        "uniform body force"
    }

    fn increment(
        &self,
        _: &FlowGrid,
        dt: f64,
        ux: ArrayView2<'_, f64>,
        uy: ArrayView2<'_, f64>,
    ) -> (Array2<f64>, Array2<f64>) {
        (
            Array2::from_elem(ux.raw_dim(), dt * self.0),
            Array2::zeros(uy.raw_dim()),
        )
    }

    fn increment_vjp(
        &self,
        _: &FlowGrid,
        _: f64,
        ux: ArrayView2<'_, f64>,
        uy: ArrayView2<'_, f64>,
        _: ArrayView2<'_, f64>,
        _: ArrayView2<'_, f64>,
    ) -> (Array2<f64>, Array2<f64>) {
        (Array2::zeros(ux.raw_dim()), Array2::zeros(uy.raw_dim()))
    }
}

/// Periodic along x, `wall` at the bottom and top of a unit-high channel.
fn channel(wall: Boundary, ny: usize, viscosity: f64, dt: f64) -> diffphys::flow::SceneBuilder {
    Scene::builder(4, ny, [4.0 / ny as f64, 1.0])
        .sides(Sides {
            bottom: wall.clone(),
            top: wall,
            ..Sides::periodic()
        })
        .viscosity(viscosity)
        .dt(dt)
}

/// The state after `steps` plain steps of `scene` from `start`.
fn run(scene: &Scene, start: &FlowState<f64>, steps: usize) -> FlowState<f64> {
    let params: FlowParams<f64> = scene.params();
    let mut s = start.clone();
    for _ in 0..steps {
        s = scene.forward(&s, &params).unwrap().0;
    }
    s
}

/// A velocity of order one with zero normal velocity on the walls' faces.
fn start(scene: &Scene, seed: u64) -> FlowState<f64> {
    let g = scene.grid();
    let mut uy = test_array::<f64>(&g.shape_y(), seed + 1).mapv(|v| 0.3 * v);
    let ny = g.shape_y()[1];
    for mut row in uy.rows_mut() {
        row[0] = 0.0;
        row[ny - 1] = 0.0;
    }
    let ux = test_array::<f64>(&g.shape_x(), seed).mapv(|v| 0.3 * v);
    FlowState::from_velocity(
        scene,
        ux.into_dimensionality().unwrap(),
        uy.into_dimensionality().unwrap(),
    )
}

#[test]
fn the_slip_walls_limits_are_the_shipped_walls_to_the_bit() {
    let scene_of = |wall: Boundary| channel(wall, 12, 0.01, 0.02).build().unwrap();
    let from = start(&scene_of(Boundary::no_slip()), 3);
    for (slip, shipped) in [
        (0.0, Boundary::new(NoSlip)),
        (1e300, Boundary::new(FreeSlip)),
    ] {
        let ours = run(
            &scene_of(Boundary::new(NavierSlip { slip_length: slip })),
            &from,
            5,
        );
        let theirs = run(&scene_of(shipped.clone()), &from, 5);
        assert_eq!(ours.ux, theirs.ux, "slip length {slip} against {shipped:?}");
        assert_eq!(ours.uy, theirs.uy, "slip length {slip} against {shipped:?}");
    }
    // In between it is neither.
    let mid = run(
        &scene_of(Boundary::new(NavierSlip { slip_length: 0.05 })),
        &from,
        5,
    );
    let no_slip = run(&scene_of(Boundary::no_slip()), &from, 5);
    assert_ne!(mid.ux, no_slip.ux);
}

#[test]
fn a_channel_between_slip_walls_reaches_the_slip_poiseuille_profile() {
    // ν u'' = −G with u(0) = λ u'(0), u(H) = −λ u'(H):
    // u(y) = G / (2ν) · (y (H − y) + λ H).
    let (g, nu, slip, ny, dt) = (0.08, 0.02, 0.1, 16, 0.04);
    let scene_of = |wall: Boundary| {
        channel(wall, ny, nu, dt)
            .forcing(Arc::new(BodyForce(g)))
            .build()
            .unwrap()
    };
    let scene = scene_of(Boundary::new(NavierSlip { slip_length: slip }));
    // The slowest mode decays like exp(−ν k² t) with cot(k/2) = λ k, k ≈ 2.76:
    // by e^-24 after t = 160.
    let end = run(&scene, &FlowState::zeros(&scene), 4000);
    let h = 1.0 / ny as f64;
    let exact = |y: f64| g / (2.0 * nu) * (y * (1.0 - y) + slip);
    // Two known differences, both exact for a quadratic profile: the ghost's
    // mean is the wall value up to u'' h² / 8, which lifts the discrete
    // profile by (G / ν) h² / 8; the step records the velocity before the
    // force of the next step, dt G below the forced one.
    let shift = g / nu * h * h / 8.0 - dt * g;
    let worst = (0..ny)
        .map(|j| (end.ux[[0, j]] - exact((j as f64 + 0.5) * h) - shift).abs())
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-9,
        "slip Poiseuille: the profile is {worst:.3e} from the analytic one shifted by {shift:.3e}"
    );
    // The same channel between no-slip walls is G λ / (2ν) = 0.2 slower at
    // the wall: the slip is what the wall did.
    let walled = run(
        &scene_of(Boundary::no_slip()),
        &FlowState::zeros(&scene),
        4000,
    );
    let slowed = end.ux[[0, 0]] - walled.ux[[0, 0]];
    assert!((slowed - 0.2).abs() < 0.05, "the slip added {slowed}");
}

/// `Σ w ⊙ u` of the velocity after 4 steps of `scene` from `(v[0], v[1])`.
fn loss_after_steps<'t>(
    scene: &Scene,
    w: &(ArrayD<f64>, ArrayD<f64>),
    tape: &'t Tape<f64>,
    v: &[Var<'t, f64>],
) -> diffphys::tape::Result<Var<'t, f64>> {
    let mut s = FlowVars::constants(tape, &FlowState::zeros(scene));
    s.ux = v[0];
    s.uy = v[1];
    let p = ParamVars::constants(tape, &scene.params());
    for _ in 0..4 {
        s = scene.step(tape, &s, &p)?.0;
    }
    s.ux.mul(tape.constant(w.0.clone()))?
        .sum()?
        .add(s.uy.mul(tape.constant(w.1.clone()))?.sum()?)
}

#[test]
fn a_step_between_slip_walls_matches_finite_differences() {
    let scene = channel(
        Boundary::new(NavierSlip { slip_length: 0.05 }),
        6,
        0.05,
        0.05,
    )
    .build()
    .unwrap();
    let from = start(&scene, 7);
    let (ux, uy): (ArrayD<f64>, ArrayD<f64>) = (from.ux.into_dyn(), from.uy.into_dyn());
    let w = (
        test_array::<f64>(ux.shape(), 21),
        test_array::<f64>(uy.shape(), 22),
    );
    let report = check_gradient(
        |tape, v| loss_after_steps(&scene, &w, tape, v),
        &[ux, uy],
        GradCheckOptions::for_type::<f64>(),
    )
    .unwrap();
    assert!(report.passed, "{report:?}");
    assert!(report.entries > 0);
}

#[test]
fn a_condition_whose_answers_do_not_fit_is_refused() {
    let err = channel(Boundary::new(Inconsistent), 8, 0.01, 0.01)
        .build()
        .unwrap_err();
    match &err {
        FlowError::InvalidScene { what, message } => {
            assert_eq!(what, "sides");
            assert!(message.contains("inconsistent"), "{message}");
        }
        other => panic!("expected InvalidScene, got {other:?}"),
    }
    // Equality is by value, through the condition's type.
    assert_eq!(
        Boundary::new(NavierSlip { slip_length: 0.1 }),
        Boundary::new(NavierSlip { slip_length: 0.1 })
    );
    assert_ne!(
        Boundary::new(NavierSlip { slip_length: 0.1 }),
        Boundary::new(NavierSlip { slip_length: 0.2 })
    );
    assert_ne!(
        Boundary::new(NavierSlip { slip_length: 0.0 }),
        Boundary::no_slip()
    );
    // A caller can ask for the condition's type.
    let wall = Boundary::new(NavierSlip { slip_length: 0.1 });
    assert_eq!(
        wall.downcast_ref::<NavierSlip>(),
        Some(&NavierSlip { slip_length: 0.1 })
    );
    assert!(wall.downcast_ref::<NoSlip>().is_none());
}
