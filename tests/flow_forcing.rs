//! The flow step's extension point is real: a body force defined here, outside
//! crates/flow (a quadratic drag, nonlinear in the velocity), joins the step
//! through `SceneBuilder::forcing` without editing the crate, and the gradient
//! of a loss through several steps with it matches central finite differences.

use std::sync::Arc;

use diffphys::flow::{
    FlowGrid, FlowState, FlowVars, Forced, Forcing, Obstacle, ParamVars, Scene, Sides,
};
use diffphys::tape::{check_gradient, test_array, ArrayD, GradCheckOptions, Tape, Var};
use ndarray::{Array2, ArrayView2};

/// `Δu = −dt c u |u|` on every face: a quadratic drag.
/// Its Jacobian is diagonal, `∂Δu/∂u = −2 dt c |u|`.
#[derive(Debug)]
struct QuadraticDrag {
    c: f64,
}

impl Forcing for QuadraticDrag {
    fn name(&self) -> &str {
        "quadratic drag"
    }

    fn increment(
        &self,
        _: &FlowGrid,
        dt: f64,
        ux: ArrayView2<'_, f64>,
        uy: ArrayView2<'_, f64>,
    ) -> (Array2<f64>, Array2<f64>) {
        let drag = |u: ArrayView2<'_, f64>| u.mapv(|v| -dt * self.c * v * v.abs());
        (drag(ux), drag(uy))
    }

    fn increment_vjp(
        &self,
        _: &FlowGrid,
        dt: f64,
        ux: ArrayView2<'_, f64>,
        uy: ArrayView2<'_, f64>,
        gx: ArrayView2<'_, f64>,
        gy: ArrayView2<'_, f64>,
    ) -> (Array2<f64>, Array2<f64>) {
        let jt = |u: ArrayView2<'_, f64>, g: ArrayView2<'_, f64>| {
            ndarray::Zip::from(u)
                .and(g)
                .map_collect(|&v, &g| -2.0 * dt * self.c * v.abs() * g)
        };
        (jt(ux, gx), jt(uy, gy))
    }
}

/// A channel with a cylinder (fixed faces the force must leave alone).
fn scene(forcing: Option<Arc<dyn Forcing>>) -> Scene {
    let builder = Scene::builder(12, 6, [2.0, 1.0])
        .sides(Sides::channel())
        .obstacle(Obstacle::cylinder([0.7, 0.5], 0.2))
        .parabolic_inflow(1.0)
        .viscosity(0.05)
        .dt(0.05);
    match forcing {
        Some(f) => builder.forcing(f),
        None => builder,
    }
    .build()
    .unwrap()
}

fn drag() -> Arc<dyn Forcing> {
    Arc::new(QuadraticDrag { c: 0.8 })
}

/// A velocity of order one that the first step's CFL check accepts.
fn velocity(scene: &Scene, seed: u64) -> (ArrayD<f64>, ArrayD<f64>) {
    let g = scene.grid();
    let s = |shape: [usize; 2], k| test_array::<f64>(&shape, k).mapv(|v| 0.8 * v);
    (s(g.shape_x(), seed), s(g.shape_y(), seed + 1))
}

#[test]
fn the_users_forcing_op_matches_finite_differences_and_spares_fixed_faces() {
    let scene = scene(None);
    let op = Forced {
        grid: scene.grid().clone(),
        faces: Arc::clone(scene.faces()),
        forcing: drag(),
        dt: 0.05,
    };
    let (ux, uy) = velocity(&scene, 3);
    let wx = test_array::<f64>(ux.shape(), 11);
    let wy = test_array::<f64>(uy.shape(), 12);
    let report = check_gradient(
        |tape: &Tape<f64>, v: &[Var<'_, f64>]| {
            let out = tape.apply_multi(op.clone(), &[v[0], v[1]])?;
            out[0]
                .mul(tape.constant(wx.clone()))?
                .sum()?
                .add(out[1].mul(tape.constant(wy.clone()))?.sum()?)
        },
        &[ux.clone(), uy.clone()],
        GradCheckOptions::for_type::<f64>(),
    )
    .unwrap();
    assert!(report.passed, "{report:?}");
    assert!(report.entries > 0);

    // The force acts on free faces only: a fixed face keeps its value.
    let tape = Tape::<f64>::new();
    let out = tape
        .apply_multi(
            op.clone(),
            &[tape.constant(ux.clone()), tape.constant(uy.clone())],
        )
        .unwrap();
    let after = out[0].to_array();
    let (changed, kept) =
        ux.iter().zip(after.iter()).fold(
            (0, 0),
            |(c, k), (a, b)| if a == b { (c, k + 1) } else { (c + 1, k) },
        );
    assert!(changed > 0, "the drag changed no face");
    assert!(kept > 0, "a channel with a cylinder has fixed x-faces");
}

/// `Σ w ⊙ u` of the velocity after `STEPS` steps of `scene` from `(v[0], v[1])`.
fn loss_after_steps<'t>(
    scene: &Scene,
    w: &(ArrayD<f64>, ArrayD<f64>),
    tape: &'t Tape<f64>,
    v: &[Var<'t, f64>],
) -> diffphys::tape::Result<Var<'t, f64>> {
    const STEPS: usize = 4;
    let mut s = FlowVars::constants(tape, &FlowState::zeros(scene));
    s.ux = v[0];
    s.uy = v[1];
    let p = ParamVars::constants(tape, &scene.params());
    for _ in 0..STEPS {
        s = scene.step(tape, &s, &p)?.0;
    }
    s.ux.mul(tape.constant(w.0.clone()))?
        .sum()?
        .add(s.uy.mul(tape.constant(w.1.clone()))?.sum()?)
}

#[test]
fn a_step_with_the_users_forcing_differentiates_through_several_steps() {
    let forced = scene(Some(drag()));
    let (ux, uy) = velocity(&forced, 5);
    let w = (
        test_array::<f64>(ux.shape(), 21),
        test_array::<f64>(uy.shape(), 22),
    );
    let report = check_gradient(
        |tape, v| loss_after_steps(&forced, &w, tape, v),
        &[ux.clone(), uy.clone()],
        GradCheckOptions::for_type::<f64>(),
    )
    .unwrap();
    assert!(report.passed, "{report:?}");
    assert!(report.entries > 0);

    // The force is in the step: the same loss without it differs.
    let value = |scene: &Scene| {
        let tape = Tape::<f64>::new();
        let v = [tape.var(ux.clone()), tape.var(uy.clone())];
        loss_after_steps(scene, &w, &tape, &v)
            .unwrap()
            .item()
            .unwrap()
    };
    let (with, without) = (value(&forced), value(&scene(None)));
    assert!(
        (with - without).abs() > 1e-6 * without.abs().max(1.0),
        "the forcing changed nothing: {with} vs {without}"
    );
}
