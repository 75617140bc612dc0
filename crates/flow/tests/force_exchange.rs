//! The force on a staircase body as the step's momentum balance sees it
//! (`ForceWeights::momentum_exchange`): on a periodic box with an obstacle,
//! where no side brings momentum in, what one explicit viscosity step and one
//! projection take out of the fluid is the force those weights give, to
//! rounding; and the force's adjoint passes the dot-product test.

mod common;

use diffphys_flow::boundaries::enforce_boundaries;
use diffphys_flow::diagnostics::{obstacle_force, obstacle_force_vjp, ForceWeights};
use diffphys_flow::diffusion::diffuse;
use diffphys_flow::pressure::project;
use diffphys_flow::{Obstacle, Scene, Sides, ViscosityMode};
use diffphys_tape::test_array;
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
