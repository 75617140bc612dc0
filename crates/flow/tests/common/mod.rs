//! Scenes and helpers shared by the flow tests.
#![allow(dead_code)]

pub mod immersed;

use diffphys_flow::{Boundary, Obstacle, PressureSolver, Scene, SceneBuilder, Sides};
use diffphys_tape::{test_array, ArrayD, Result as TapeResult, Tape, Var};
use ndarray::{Array2, IxDyn};

/// A 12 × 6 channel 2 × 1 with a cylinder and a parabolic inflow.
pub fn channel() -> SceneBuilder {
    Scene::builder(12, 6, [2.0, 1.0])
        .sides(Sides::channel())
        .obstacle(Obstacle::cylinder([0.7, 0.5], 0.2))
        .parabolic_inflow(1.0)
        .viscosity(0.05)
        .dt(0.05)
}

/// A 6 × 6 lid-driven cavity.
pub fn cavity() -> SceneBuilder {
    Scene::builder(6, 6, [1.0, 1.0])
        .sides(Sides::cavity(1.0))
        .viscosity(0.05)
        .dt(0.05)
}

/// Every kind of side but inflow and periodic, and a box obstacle.
pub fn mixed() -> SceneBuilder {
    Scene::builder(8, 7, [1.0, 1.0])
        .sides(mixed_sides())
        .obstacle(Obstacle::rectangle([0.4, 0.3], [0.7, 0.65]))
        .viscosity(0.02)
        .dt(0.04)
}

/// Every kind of side but inflow and periodic.
pub fn mixed_sides() -> Sides {
    Sides {
        left: Boundary::no_slip(),
        right: Boundary::outflow(),
        bottom: Boundary::moving_wall(0.5),
        top: Boundary::free_slip(),
    }
}

/// A 6 × 5 periodic box.
pub fn periodic() -> SceneBuilder {
    Scene::builder(6, 5, [1.0, 1.0])
        .sides(Sides::periodic())
        .viscosity(0.03)
        .dt(0.04)
}

/// All five test scenes, named: the periodic box twice, with the sparse
/// Cholesky and the Fourier pressure solve.
pub fn scenes() -> Vec<(&'static str, SceneBuilder)> {
    vec![
        ("channel", channel()),
        ("cavity", cavity()),
        ("mixed", mixed()),
        ("periodic", periodic()),
        (
            "periodic (Fourier)",
            periodic().pressure_solver(PressureSolver::Fourier),
        ),
    ]
}

/// A random velocity of amplitude `amp` on the scene's faces.
pub fn velocity(scene: &Scene, amp: f64, seed: u64) -> (Array2<f64>, Array2<f64>) {
    let g = scene.grid();
    let two = |s: [usize; 2], k| {
        test_array::<f64>(&s, k)
            .mapv(|v| amp * v)
            .into_dimensionality()
            .unwrap()
    };
    (two(g.shape_x(), seed), two(g.shape_y(), seed + 1))
}

/// `Σ_k <out_k, w_k>` with fixed pseudo-random weights: one scalar that sees
/// every output.
pub fn combine<'t>(tape: &'t Tape<f64>, outs: &[Var<'t, f64>]) -> TapeResult<Var<'t, f64>> {
    let mut total: Option<Var<'t, f64>> = None;
    for (k, o) in outs.iter().enumerate() {
        let w = tape.constant(test_array::<f64>(&o.shape(), 100 + k as u64));
        let t = o.dot(w)?;
        total = Some(match total {
            Some(s) => s.add(t)?,
            None => t,
        });
    }
    Ok(total.expect("at least one output"))
}

/// Flattens arrays into one vector.
pub fn pack(parts: &[&Array2<f64>]) -> ArrayD<f64> {
    let v: Vec<f64> = parts.iter().flat_map(|a| a.iter().copied()).collect();
    ArrayD::from_shape_vec(IxDyn(&[v.len()]), v).unwrap()
}

/// Splits a flat vector into arrays of `shapes`.
pub fn unpack(v: &ArrayD<f64>, shapes: &[[usize; 2]]) -> Vec<Array2<f64>> {
    let s = v.as_slice().unwrap();
    let mut off = 0;
    shapes
        .iter()
        .map(|sh| {
            let n = sh[0] * sh[1];
            let a = Array2::from_shape_vec((sh[0], sh[1]), s[off..off + n].to_vec()).unwrap();
            off += n;
            a
        })
        .collect()
}

/// A 0-d array.
pub fn scalar(v: f64) -> ArrayD<f64> {
    ArrayD::from_elem(IxDyn(&[]), v)
}
