//! diffphys's implicit Poisson solve inside a candle model.
//!
//! A candle model with 16 parameters — the amplitudes `a_k` of Gaussian sources
//! `φ_k` centred on a 4 × 4 lattice — produces a right-hand side
//! `b = Σ_k a_k φ_k` (one matrix product); our Poisson solve (`−∇² x = b`, 64²
//! cells, zero walls, CG to relative tolerance 1e-10, wrapped as a candle custom
//! op) turns it into a potential `x`, and the loss `‖x − x_obs‖² / ‖x_obs‖²`
//! compares it with an observed potential made by hidden amplitudes. candle's
//! `backward` differentiates through the solve with one adjoint CG solve; plain
//! gradient descent trains the amplitudes.
//!
//! The same model is built on our tape, trained from the same start with the
//! same steps, and the two runs compared: the largest gradient difference over
//! all steps, seconds per training step for each, and what the wrapping costs
//! (copying the field between candle's storage and ndarray and back).
//!
//! Tutorial: docs/09-from-another-engine.md. Run:
//! `cargo run --release --example candle_interop` (`-- --small` for 32² cells
//! and 10 steps, `-- --iterations N`, `-- --out DIR`).

mod common;

use std::sync::Arc;
use std::time::Instant;

use candle_core::{Device, Tensor, Var as CandleVar};
use diffphys::ops::cg::CgParams;
use diffphys::ops::poisson::PoissonSolve;
use diffphys::ops::stencil::Laplacian2;
use diffphys::prelude::*;
use diffphys::report::chart::{line_chart_svg, LineChart, Series};
use diffphys_candle::CandlePoisson;
use ndarray::{Array1, Array2};

type BoxError = Box<dyn std::error::Error>;

/// Sources on a `SIDE × SIDE` lattice.
const SIDE: usize = 4;
const SOURCES: usize = SIDE * SIDE;
const LEARNING_RATE: f64 = 0.5;

/// The scene: the basis of sources `[SOURCES, n²]`, the observed potential, the
/// operator and the CG settings.
struct Scene {
    n: usize,
    basis: Array2<f64>,
    observed: ArrayD<f64>,
    op: Arc<Laplacian2>,
    params: CgParams,
    /// `1 / ‖x_obs‖²`.
    inv_norm2: f64,
}

impl Scene {
    fn new(n: usize) -> Result<Self, BoxError> {
        let grid = Grid2::new(
            n,
            n,
            1.0 / n as f64,
            1.0 / n as f64,
            Boundary::ZeroDirichlet,
        )?;
        let op = Arc::new(Laplacian2::negative(grid));
        let params = CgParams {
            rel_tol: 1e-10,
            ..CgParams::default()
        };
        let width = 0.08;
        let mut basis = Array2::zeros((SOURCES, n * n));
        for k in 0..SOURCES {
            let (cx, cy) = (
                (0.5 + (k % SIDE) as f64) / SIDE as f64,
                (0.5 + (k / SIDE) as f64) / SIDE as f64,
            );
            for i in 0..n {
                for j in 0..n {
                    let (x, y) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                    let r2 = (x - cx).powi(2) + (y - cy).powi(2);
                    basis[[k, i * n + j]] = (-r2 / (2.0 * width * width)).exp();
                }
            }
        }
        // Hidden amplitudes: a smooth pattern of signs and sizes.
        let hidden =
            Array1::from_shape_fn(SOURCES, |k| (1.7 * k as f64).sin() * (1.0 + 0.1 * k as f64));
        let b = hidden.dot(&basis).into_shape_with_order((n, n))?.into_dyn();
        let (observed, _) = diffphys::ops::poisson::poisson_solve(&*op, b.view(), &params)?;
        let inv_norm2 = 1.0 / observed.iter().map(|v| v * v).sum::<f64>();
        Ok(Scene {
            n,
            basis,
            observed,
            inv_norm2,
            op,
            params,
        })
    }

    /// Loss and gradient of the amplitudes with candle and our Poisson op.
    fn candle_step(
        &self,
        solve: &CandlePoisson<Laplacian2>,
        a: &CandleVar,
        basis: &Tensor,
        observed: &Tensor,
    ) -> Result<(f64, Vec<f64>), BoxError> {
        let b = a.as_tensor().matmul(basis)?.reshape((self.n, self.n))?;
        let x = solve.apply(&b)?;
        let loss = x
            .sub(observed)?
            .sqr()?
            .sum_all()?
            .affine(self.inv_norm2, 0.0)?;
        let grads = loss.backward()?;
        let g = grads.get(a.as_tensor()).ok_or("candle gave no gradient")?;
        Ok((loss.to_scalar::<f64>()?, g.flatten_all()?.to_vec1::<f64>()?))
    }

    /// The same loss and gradient on our tape.
    fn tape_step(&self, a: &[f64]) -> Result<(f64, Vec<f64>), BoxError> {
        let tape = Tape::<f64>::new();
        let av = tape.var(Array2::from_shape_vec((1, SOURCES), a.to_vec())?.into_dyn());
        let b = av
            .matmul(tape.constant(self.basis.clone().into_dyn()))?
            .reshape(&[self.n, self.n])?;
        let x = b.tape().apply(
            PoissonSolve::new(Arc::clone(&self.op), self.params.clone()),
            &[b],
        )?;
        let loss = x
            .sub(tape.constant(self.observed.clone()))?
            .powi(2)?
            .sum()?
            .mul_scalar(self.inv_norm2)?;
        let g = tape.backward(loss, &[av])?;
        let g = g.get(av).ok_or("the tape gave no gradient")?;
        Ok((loss.item()?, g.iter().copied().collect()))
    }
}

/// Seconds for the one copy the wrapped solve makes per step: the incoming
/// gradient field copied out of candle into an ndarray array in the backward
/// (the forward reads candle's buffer in place and moves its result into
/// candle; best of 20).
fn copy_seconds(n: usize) -> Result<f64, BoxError> {
    let t = Tensor::ones((n, n), candle_core::DType::F64, &Device::Cpu)?;
    let mut best = f64::INFINITY;
    for _ in 0..20 {
        let start = Instant::now();
        let v = t.flatten_all()?.to_vec1::<f64>()?;
        let a = ArrayD::from_shape_vec(vec![n, n], v)?;
        std::hint::black_box(a);
        best = best.min(start.elapsed().as_secs_f64());
    }
    Ok(best)
}

/// The median of the per-step times (steps alternate between the two engines,
/// so both see the same machine).
fn median(seconds: &mut [f64]) -> f64 {
    seconds.sort_by(f64::total_cmp);
    seconds[seconds.len() / 2]
}

/// diffphys's implicit Poisson solve inside a candle model, trained beside the
/// same model on our tape.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    /// Training steps (10 with --small).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 40,
        default_value_if("small", "true", "10")
    )]
    iterations: usize,
}

fn main() -> Result<(), BoxError> {
    let Cli {
        common: args,
        iterations: steps,
    } = common::parse_args("candle_interop")?;
    let n = args.pick(64, 32);
    let scene = Scene::new(n)?;
    println!("candle model → diffphys Poisson solve: {n}² cells, {SOURCES} amplitudes, {steps} gradient steps");

    let solve = CandlePoisson::new(Arc::clone(&scene.op), scene.params.clone());
    let basis = Tensor::from_vec(
        scene.basis.iter().copied().collect::<Vec<_>>(),
        (SOURCES, n * n),
        &Device::Cpu,
    )?;
    let observed = Tensor::from_vec(
        scene.observed.iter().copied().collect::<Vec<_>>(),
        (n, n),
        &Device::Cpu,
    )?;
    let a_candle = CandleVar::zeros((1, SOURCES), candle_core::DType::F64, &Device::Cpu)?;
    let mut a_tape = vec![0.0; SOURCES];

    let (mut max_diff, mut max_grad) = (0.0_f64, 0.0_f64);
    let (mut candle_seconds, mut tape_seconds) = (Vec::new(), Vec::new());
    let (mut candle_losses, mut tape_losses) = (Vec::new(), Vec::new());
    for step in 0..steps {
        let start = Instant::now();
        let (loss_c, grad_c) = scene.candle_step(&solve, &a_candle, &basis, &observed)?;
        let update = Tensor::from_vec(grad_c.clone(), (1, SOURCES), &Device::Cpu)?
            .affine(LEARNING_RATE, 0.0)?;
        a_candle.set(&a_candle.as_tensor().sub(&update)?)?;
        candle_seconds.push(start.elapsed().as_secs_f64());

        let start = Instant::now();
        let (loss_t, grad_t) = scene.tape_step(&a_tape)?;
        for (a, g) in a_tape.iter_mut().zip(&grad_t) {
            *a -= LEARNING_RATE * g;
        }
        tape_seconds.push(start.elapsed().as_secs_f64());

        for (c, t) in grad_c.iter().zip(&grad_t) {
            max_diff = max_diff.max((c - t).abs());
            max_grad = max_grad.max(t.abs());
        }
        candle_losses.push((step as f64, loss_c));
        tape_losses.push((step as f64, loss_t));
        if step % 10 == 0 || step + 1 == steps {
            println!("step {step:3}: loss candle {loss_c:.6e}, tape {loss_t:.6e}");
        }
    }
    let per_step_candle = median(&mut candle_seconds);
    let per_step_tape = median(&mut tape_seconds);
    let copies = copy_seconds(n)?;
    let loss_drop = candle_losses[steps - 1].1 / candle_losses[0].1;
    println!(
        "max |gradient candle − tape| over {steps} steps: {max_diff:.2e} (largest gradient entry {max_grad:.2e})\n\
         seconds per step: candle {per_step_candle:.4}, tape {per_step_tape:.4} (candle/tape {:.3})\n\
         the copy per step (the gradient field out of candle in the backward): {:.1} µs, {:.3}% of a candle step\n\
         loss fell by {loss_drop:.2e} (candle)",
        per_step_candle / per_step_tape,
        copies * 1e6,
        100.0 * copies / per_step_candle,
    );

    line_chart_svg(
        &args.out.join("loss.svg"),
        &LineChart {
            title: "candle model through the diffphys Poisson solve: training loss",
            x_label: "gradient step",
            y_label: "relative squared potential error",
            log_x: false,
            log_y: true,
            series: &[
                Series::new("candle", candle_losses),
                Series::new("diffphys tape", tape_losses),
            ],
        },
    )?;
    println!("chart written to {}", args.out.join("loss.svg").display());
    let amplitudes = ndarray::Array1::from(a_tape.clone()).into_dyn();
    let amplitudes_candle =
        ndarray::Array1::from(a_candle.as_tensor().flatten_all()?.to_vec1::<f64>()?).into_dyn();
    args.write_npy(&[
        (
            "observed",
            scene.observed.view(),
            "the observed potential x_obs [n, n]",
        ),
        (
            "amplitudes_tape",
            amplitudes.view(),
            "the trained source amplitudes, tape [16]",
        ),
        (
            "amplitudes_candle",
            amplitudes_candle.view(),
            "the trained source amplitudes, candle [16]",
        ),
    ])?;

    common::print_json_line(&serde_json::json!({
        "n": n,
        "steps": steps,
        "max_abs_diff_candle_vs_tape": max_diff,
        "max_abs_gradient": max_grad,
        "seconds_per_step_candle": per_step_candle,
        "seconds_per_step_tape": per_step_tape,
        "seconds_copy_per_step": copies,
        "loss_ratio_last_over_first": loss_drop,
    }));
    Ok(())
}
