//! Recovering a conductivity field from observations of the potential: the
//! inverse problem behind docs/03-implicit-gradients.md's last section.
//!
//! On the unit square with zero-Dirichlet walls, four sources `b_s` drive
//! potentials `p_s = A(k)⁻¹ b_s` through `A(k) = −∇·(k ∇·)`. From the potentials
//! of the true conductivity (an inclusion of high and one of low conductivity
//! in a background of 1), we recover `k = exp(θ)` by Adam on
//!
//! ```text
//! L(θ) = Σ_s ½‖p_s(e^θ) − p_s^obs‖² / Σ_s ‖p_s^obs‖² + (α/2) Σ_faces (θ_i − θ_j)²
//! ```
//!
//! The gradient in `θ` flows through the conductivity input of the Poisson op
//! on the tape ([`ConductivitySolve`]): per source, one adjoint solve gives
//! `∂L/∂k = −λᵀ (∂A/∂k) p`. At the first iterate it is compared with the same
//! gradient from exact sparse-Cholesky solves.
//!
//! ```sh
//! cargo run --release --example inverse_conductivity            # 32², 300 iterations
//! cargo run --release --example inverse_conductivity -- --small # 16², 120 iterations
//! cargo run --release --example inverse_conductivity -- --npy   # also OUT/npy/*.npy
//! ```

mod common;

use std::path::Path;
use std::time::Instant;

use diffphys::ops::cg::CgParams;
use diffphys::ops::cg::NullSpace;
use diffphys::ops::conductivity::{Conductivity2, ConductivitySolve};
use diffphys::ops::reference::SparseCholesky;
use diffphys::prelude::*;
use diffphys::report::chart::{heatmap_svg_with_axes, line_chart_svg, LineChart, Series};
use diffphys::tape::optim::{Adam, Optimizer};
use ndarray::{Array2, Ix2};

type BoxError = Box<dyn std::error::Error>;

/// Weight of the smoothness penalty on `θ = ln k`.
const ALPHA: f64 = 1e-5;

/// The grid, the sources and the observed potentials.
struct Scene {
    grid: Grid2,
    k_true: Array2<f64>,
    sources: Vec<ArrayD<f64>>,
    observed: Vec<ArrayD<f64>>,
    /// `Σ_s ‖p_s^obs‖²`, the misfit's normalisation.
    norm: f64,
}

impl Scene {
    fn new(n: usize) -> Result<Self, BoxError> {
        let grid = Grid2::square(n, n, 1.0 / n as f64, Boundary::ZeroDirichlet)?;
        let bump = |x: [f64; 2], c: [f64; 2], s: f64| {
            (-((x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2)) / (2.0 * s * s)).exp()
        };
        let k_true = Array2::from_shape_fn((n, n), |(i, j)| {
            let x = grid.center(i, j);
            1.0 + 2.0 * bump(x, [0.35, 0.6], 0.12) - 0.6 * bump(x, [0.7, 0.3], 0.1)
        });
        // Sources of different shapes, so that ∇p sweeps every direction.
        let shapes: [fn([f64; 2]) -> f64; 4] = [
            |_| 1.0,
            |x| (std::f64::consts::PI * x[0]).sin() * 4.0 * (x[1] - 0.5),
            |x| 4.0 * (x[0] - 0.5) * (std::f64::consts::PI * x[1]).sin(),
            |x| 10.0 * (-((x[0] - 0.5).powi(2) + (x[1] - 0.5).powi(2)) / 0.02).exp(),
        ];
        let sources: Vec<ArrayD<f64>> = shapes
            .iter()
            .map(|f| Array2::from_shape_fn((n, n), |(i, j)| f(grid.center(i, j))).into_dyn())
            .collect();
        let exact =
            SparseCholesky::new(&Conductivity2::new(grid, k_true.view())?, NullSpace::None)?;
        let observed = sources
            .iter()
            .map(|b| exact.solve(b.view()))
            .collect::<Result<Vec<_>, _>>()?;
        let norm = observed.iter().map(|p| p.mapv(|v| v * v).sum()).sum();
        Ok(Scene {
            grid,
            k_true,
            sources,
            observed,
            norm,
        })
    }

    /// The data misfit `Σ_s ½‖p_s − p_s^obs‖² / norm` of `k = e^θ`, on θ's tape.
    fn misfit<'t>(&self, theta: Var<'t, f64>) -> Result<Var<'t, f64>, BoxError> {
        let tape = theta.tape();
        let k = theta.exp()?;
        let params = CgParams::default().with_rel_tol(1e-10);
        let mut total = tape.scalar(0.0);
        for (b, obs) in self.sources.iter().zip(&self.observed) {
            let solve = ConductivitySolve::new(self.grid, params.clone());
            let p = tape.apply(solve, &[tape.constant(b.clone()), k])?;
            let d = p.sub(tape.constant(obs.clone()))?;
            total = total.add(d.mul(d)?.sum()?)?;
        }
        Ok(total.mul_scalar(0.5 / self.norm)?)
    }

    /// `(α/2) Σ (θ_i − θ_j)²` over the interior faces.
    fn smoothness<'t>(&self, theta: Var<'t, f64>) -> Result<Var<'t, f64>, BoxError> {
        let n = self.grid.nx;
        let mut total = theta.tape().scalar(0.0);
        for axis in [0, 1] {
            let d = theta.slice(axis, 1, n)?.sub(theta.slice(axis, 0, n - 1)?)?;
            total = total.add(d.mul(d)?.sum()?)?;
        }
        Ok(total.mul_scalar(0.5 * ALPHA)?)
    }

    /// `∂ misfit/∂θ` from exact sparse-Cholesky solves: per source
    /// `λ_s = A⁻¹ (p_s − p_s^obs)/norm`, then `−k ⊙ Σ_s ∂(λ_sᵀ A p_s)/∂k`.
    fn exact_misfit_gradient(&self, theta: &Array2<f64>) -> Result<Array2<f64>, BoxError> {
        let k = theta.mapv(f64::exp);
        let a = Conductivity2::new(self.grid, k.view())?;
        let chol = SparseCholesky::new(&a, NullSpace::None)?;
        let mut g = Array2::<f64>::zeros(k.raw_dim());
        for (b, obs) in self.sources.iter().zip(&self.observed) {
            let p = chol.solve(b.view())?;
            let lambda = chol.solve(((&p - obs) / self.norm).view())?;
            let dk = a.coefficient_vjp(p.view(), lambda.view())?;
            g -= &dk.into_dimensionality::<Ix2>()?;
        }
        Ok(g * &k)
    }
}

fn rel_error(a: &Array2<f64>, b: &Array2<f64>) -> f64 {
    ((a - b).mapv(|v| v * v).sum() / b.mapv(|v| v * v).sum()).sqrt()
}

fn write_charts(
    out: &Path,
    scene: &Scene,
    k: &Array2<f64>,
    losses: &[f64],
) -> Result<(), BoxError> {
    let axes = ["x", "y"];
    heatmap_svg_with_axes(
        &out.join("k_true.svg"),
        "true conductivity k",
        scene.k_true.view(),
        axes,
    )?;
    heatmap_svg_with_axes(
        &out.join("k_recovered.svg"),
        "recovered conductivity k",
        k.view(),
        axes,
    )?;
    let error = k - &scene.k_true;
    heatmap_svg_with_axes(
        &out.join("k_error.svg"),
        "recovered − true k",
        error.view(),
        axes,
    )?;
    let points = losses
        .iter()
        .enumerate()
        .map(|(i, &l)| (i as f64, l))
        .collect();
    line_chart_svg(
        &out.join("loss.svg"),
        &LineChart {
            title: "inverse_conductivity: loss per Adam iteration",
            x_label: "iteration",
            y_label: "loss (misfit + smoothness)",
            log_x: false,
            log_y: true,
            series: &[Series::new("implicit gradient in k", points)],
        },
    )?;
    Ok(())
}

/// Recovers a conductivity field from observations of the potential.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    /// Adam iterations (120 with --small).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 300,
        default_value_if("small", "true", "120")
    )]
    iterations: usize,
}

fn main() -> Result<(), BoxError> {
    let Cli {
        common: args,
        iterations,
    } = common::parse_args("inverse_conductivity")?;
    let n = args.pick(32, 16);
    if iterations == 0 {
        return Err("--iterations must be at least 1".into());
    }
    let scene = Scene::new(n)?;

    // The first gradient against the exact one.
    let theta0 = Array2::<f64>::zeros((n, n));
    let tape = Tape::<f64>::new();
    let theta = tape.var(theta0.clone().into_dyn());
    let misfit = scene.misfit(theta)?;
    let grads = tape.backward(misfit, &[theta])?;
    let g_tape = grads
        .get(theta)
        .ok_or("no gradient for θ")?
        .clone()
        .into_dimensionality::<Ix2>()?;
    let g_exact = scene.exact_misfit_gradient(&theta0)?;
    let grad_error = rel_error(&g_tape, &g_exact);
    println!("first gradient vs exact (sparse Cholesky): relative error {grad_error:.3e}");

    let mut params = vec![theta0.into_dyn()];
    let mut adam = Adam::new(0.05);
    let mut losses = Vec::with_capacity(iterations);
    let start = Instant::now();
    println!("iteration        loss   ‖k − k_true‖/‖k_true‖ (before the step)");
    for it in 0..iterations {
        let tape = Tape::<f64>::new();
        let theta = tape.var(params[0].clone());
        let loss = scene.misfit(theta)?.add(scene.smoothness(theta)?)?;
        losses.push(loss.item()?);
        if it % (iterations / 10).max(1) == 0 || it + 1 == iterations {
            let k = params[0].mapv(f64::exp).into_dimensionality::<Ix2>()?;
            println!(
                "{it:>9} {:>11.4e} {:>12.4}",
                losses[it],
                rel_error(&k, &scene.k_true)
            );
        }
        let grads = tape.backward(loss, &[theta])?;
        adam.step_vars(&mut params, &grads, &[theta])?;
    }
    let seconds = start.elapsed().as_secs_f64();
    let k = params[0].mapv(f64::exp).into_dimensionality::<Ix2>()?;
    let initial_error = rel_error(&Array2::ones((n, n)), &scene.k_true);
    let coefficient_error = rel_error(&k, &scene.k_true);
    println!(
        "{n}²: conductivity error {initial_error:.3} (k = 1) → {coefficient_error:.3} after \
         {iterations} Adam iterations, {:.2} ms per iteration ({} sources, forward and adjoint \
         solve each)",
        1e3 * seconds / iterations as f64,
        scene.sources.len()
    );
    write_charts(&args.out, &scene, &k, &losses)?;
    let observed = ndarray::stack(
        ndarray::Axis(0),
        &scene.observed.iter().map(|o| o.view()).collect::<Vec<_>>(),
    )?;
    args.write_npy(&[
        (
            "k_true",
            scene.k_true.view().into_dyn(),
            "the true conductivity [n, n]",
        ),
        (
            "k_recovered",
            k.view().into_dyn(),
            "the conductivity exp(θ) after the last Adam step [n, n]",
        ),
        (
            "observed",
            observed.view(),
            "the observed potentials p_s of the true conductivity, one per source [sources, n, n]",
        ),
        (
            "grad_theta_first",
            g_tape.view().into_dyn(),
            "dL/dθ of the misfit at θ = 0 (k = 1), by the implicit adjoint on the tape [n, n]",
        ),
        (
            "grad_theta_first_exact",
            g_exact.view().into_dyn(),
            "the same gradient from exact sparse-Cholesky solves [n, n]",
        ),
    ])?;
    // Fail loudly rather than print figures that contradict the tutorial.
    if grad_error > 1e-8 {
        return Err(
            format!("first gradient is {grad_error:.3e} from exact (expected ≤ 1e-8)").into(),
        );
    }
    if coefficient_error > 0.1 * initial_error {
        return Err(format!(
            "conductivity error {coefficient_error:.3} is not a tenth of the initial {initial_error:.3}"
        )
        .into());
    }
    println!("charts written to {}", args.out.display());
    common::print_json_line(&serde_json::json!({
        "example": "inverse_conductivity",
        "n": n,
        "iterations": iterations,
        "grad_rel_err_vs_exact": grad_error,
        "coefficient_rel_error": coefficient_error,
        "coefficient_rel_error_initial": initial_error,
        "loss_initial": losses[0],
        "loss_final": losses[iterations - 1],
        "seconds_per_iteration": seconds / iterations as f64,
    }));
    Ok(())
}
