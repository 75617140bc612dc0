//! The seed's inverse problem: find a velocity `u(x)`, constant in time, whose
//! first-order upwind advection carries a smooth density bump `d⁰` onto a shifted
//! target over many steps. The loss `|d(t_e) − d_target|²` is differentiated
//! through every step, the gradients of all steps accumulating into `u`, and `u`
//! follows plain gradient descent.
//!
//! The problem is solved twice: with the monolithic upwind op (one tape node per
//! step, adjoint by hand) and with the same scheme written in tape primitives
//! (`roll`, `minimum`, `maximum`, `mul`, `sub`, …: twelve nodes per step). The
//! gradients must agree to 1e-10; the example reports the tape memory and time
//! of both.
//!
//! Tutorial: docs/02-advection-inverse-problems.md. Run:
//! `cargo run --release --example advection_inverse` (`-- --small` for the CI size).

mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use diffphys::ops::advection::{AdvectionParams, Upwind1};
use diffphys::prelude::*;
use diffphys::report::chart::{line_chart_svg, LineChart, Series};
use ndarray::Array1;

type BoxError = Box<dyn std::error::Error>;

/// The scene: grid, time stepping, initial density and target.
struct Scene {
    grid: Grid1,
    params: AdvectionParams,
    steps: usize,
    d0: ArrayD<f64>,
    target: ArrayD<f64>,
}

/// A smooth bump centred at `c` on the periodic unit interval.
fn bump(x: f64, c: f64) -> f64 {
    let r = (x - c + 0.5).rem_euclid(1.0) - 0.5; // periodic distance
    (-(r / 0.08).powi(2)).exp()
}

impl Scene {
    /// `n` cells on [0, 1], `steps` steps up to t = 1; the bump starts at 0.3 and
    /// must end at 0.6 (a mean velocity of 0.3).
    fn new(n: usize, steps: usize) -> Result<Self, BoxError> {
        let grid = Grid1::over(0.0, 1.0, n, Boundary::Periodic)?;
        let x = Array1::from(grid.centers());
        Ok(Scene {
            grid,
            params: AdvectionParams::new(1.0 / steps as f64),
            steps,
            d0: x.mapv(|x| bump(x, 0.3)).into_dyn(),
            target: x.mapv(|x| bump(x, 0.6)).into_dyn(),
        })
    }
}

/// One advection step as the monolithic op.
fn step_op<'t>(scene: &Scene, d: Var<'t, f64>, u: Var<'t, f64>) -> Result<Var<'t, f64>, BoxError> {
    Ok(d.tape()
        .apply(Upwind1::new(scene.grid, scene.params), &[d, u])?)
}

/// The same step in tape primitives, following the seed formula literally:
/// `d' = d − dt·[min(u/dx, 0)·(d_{i+1} − d_i) + max(u/dx, 0)·(d_i − d_{i−1})]`
/// with periodic neighbours by `roll`. `0.minimum(·)` and `0.maximum(·)` send the
/// gradient to the constant on ties, so the derivative at `u = 0` is 0, as in the op.
fn step_primitives<'t>(
    scene: &Scene,
    d: Var<'t, f64>,
    u: Var<'t, f64>,
) -> Result<Var<'t, f64>, BoxError> {
    let zero = d.tape().scalar(0.0);
    let c = u.mul_scalar(1.0 / scene.grid.dx)?;
    let u_plus = zero.minimum(c)?;
    let u_minus = zero.maximum(c)?;
    let forward = d.roll(-1, 0)?.sub(d)?; // d_{i+1} − d_i
    let backward = d.sub(d.roll(1, 0)?)?; // d_i − d_{i−1}
    let rate = u_plus.mul(forward)?.add(u_minus.mul(backward)?)?;
    Ok(d.sub(rate.mul_scalar(scene.params.dt)?)?)
}

type Step = for<'t> fn(&Scene, Var<'t, f64>, Var<'t, f64>) -> Result<Var<'t, f64>, BoxError>;

/// What one loss-and-gradient evaluation measured.
struct Evaluation {
    loss: f64,
    grad: ArrayD<f64>,
    final_density: ArrayD<f64>,
    peak_bytes: usize,
    nodes: usize,
    elapsed: Duration,
}

/// `|d(t_e) − d_target|²` after all steps, and its gradient in `u`.
fn evaluate(scene: &Scene, u: &ArrayD<f64>, step: Step) -> Result<Evaluation, BoxError> {
    let start = Instant::now();
    let tape = Tape::<f64>::new();
    let uv = tape.var(u.clone());
    let mut d = tape.constant(scene.d0.clone());
    for _ in 0..scene.steps {
        d = step(scene, d, uv)?;
    }
    let residual = d.sub(tape.constant(scene.target.clone()))?;
    let loss = residual.dot(residual)?;
    let mut grads = tape.backward(loss, &[uv])?;
    let elapsed = start.elapsed();
    let stats = tape.stats();
    Ok(Evaluation {
        loss: loss.item()?,
        grad: grads.take(uv).ok_or("no gradient for u")?,
        final_density: d.to_array(),
        peak_bytes: stats.peak_bytes,
        nodes: stats.nodes,
        elapsed,
    })
}

/// Gradient descent on `u`, evaluating the loss and gradient with both the op and
/// the primitives at every iterate (descending with the op's gradient), so the two
/// gradients are compared at the same velocity.
struct Run {
    losses: Vec<f64>,
    u: ArrayD<f64>,
    final_density: ArrayD<f64>,
    /// The op's gradient at the last iterate that took a step.
    grad: ArrayD<f64>,
    /// `max |grad_op − grad_primitives|` and `max |grad_op|` over all iterates.
    grad_diff: f64,
    grad_max: f64,
    /// Peak tape bytes and nodes of one evaluation: op, primitives.
    peak_bytes: (usize, usize),
    nodes: (usize, usize),
    /// Total forward + backward time: op, primitives.
    time: (Duration, Duration),
}

fn descend(
    scene: &Scene,
    u0: &ArrayD<f64>,
    iterations: usize,
    learning_rate: f64,
) -> Result<Run, BoxError> {
    let mut u = u0.clone();
    let mut run = Run {
        losses: Vec::new(),
        u: u.clone(),
        final_density: scene.d0.clone(),
        grad: ArrayD::zeros(u0.raw_dim()),
        grad_diff: 0.0,
        grad_max: 0.0,
        peak_bytes: (0, 0),
        nodes: (0, 0),
        time: (Duration::ZERO, Duration::ZERO),
    };
    for it in 0..=iterations {
        // Alternate which goes first, so neither always runs on a warm cache.
        let (op, primitives) = if it % 2 == 0 {
            let op = evaluate(scene, &u, step_op)?;
            (op, evaluate(scene, &u, step_primitives)?)
        } else {
            let primitives = evaluate(scene, &u, step_primitives)?;
            (evaluate(scene, &u, step_op)?, primitives)
        };
        run.losses.push(op.loss);
        run.final_density = op.final_density;
        if it == iterations {
            break; // the loss at the final velocity, for the record
        }
        run.time.0 += op.elapsed;
        run.time.1 += primitives.elapsed;
        run.peak_bytes = (op.peak_bytes, primitives.peak_bytes);
        run.nodes = (op.nodes, primitives.nodes);
        for (a, b) in op.grad.iter().zip(primitives.grad.iter()) {
            run.grad_diff = run.grad_diff.max((a - b).abs());
            run.grad_max = run.grad_max.max(a.abs());
        }
        u.scaled_add(-learning_rate, &op.grad);
        run.grad = op.grad;
    }
    run.u = u;
    Ok(run)
}

fn write_charts(out: &Path, scene: &Scene, run: &Run) -> Result<Vec<PathBuf>, BoxError> {
    let x = scene.grid.centers();
    let curve = |label: &str, v: &ArrayD<f64>| {
        Series::new(label, x.iter().copied().zip(v.iter().copied()).collect())
    };
    let losses = |label: &str, l: &[f64]| {
        Series::new(
            label,
            l.iter().enumerate().map(|(i, &v)| (i as f64, v)).collect(),
        )
    };
    let loss_path = out.join("advection_loss.svg");
    line_chart_svg(
        &loss_path,
        &LineChart {
            title: "Advection inverse problem: loss per gradient-descent iteration",
            x_label: "iteration",
            y_label: "|d(t_e) - d_target|^2",
            log_x: false,
            log_y: true,
            series: &[losses("loss", &run.losses)],
        },
    )?;
    let density_path = out.join("advection_density.svg");
    line_chart_svg(
        &density_path,
        &LineChart {
            title: "Density: initial, target, and carried by the learned velocity",
            x_label: "x",
            y_label: "d",
            log_x: false,
            log_y: false,
            series: &[
                curve("d0", &scene.d0),
                curve("target", &scene.target),
                curve("d(t_e), learned u", &run.final_density),
            ],
        },
    )?;
    let velocity_path = out.join("advection_velocity.svg");
    line_chart_svg(
        &velocity_path,
        &LineChart {
            title: "Learned velocity u(x), constant in time",
            x_label: "x",
            y_label: "u",
            log_x: false,
            log_y: false,
            series: &[curve("u", &run.u)],
        },
    )?;
    Ok(vec![loss_path, density_path, velocity_path])
}

/// Finds the velocity whose upwind advection carries a bump onto a target, by
/// gradient descent through every step.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    /// Gradient-descent iterations (10 with --small).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 100,
        default_value_if("small", "true", "10")
    )]
    iterations: usize,
}

fn main() -> Result<(), BoxError> {
    let Cli {
        common: args,
        iterations,
    } = common::parse_args("advection_inverse")?;
    let n = args.pick(128, 32);
    let steps = args.pick(200, 40);
    let scene = Scene::new(n, steps)?;
    // Courant number of the initial guess: 0.1·dt/dx = 0.1·n/steps.
    let u0 = ArrayD::from_elem(vec![n], 0.1);
    let learning_rate = 0.02;

    let run = descend(&scene, &u0, iterations, learning_rate)?;

    let (op_time, primitives_time) = (run.time.0.as_secs_f64(), run.time.1.as_secs_f64());
    let time_ratio = primitives_time / op_time;
    let memory_ratio = run.peak_bytes.1 as f64 / run.peak_bytes.0 as f64;
    let (loss_initial, loss_final) = (run.losses[0], *run.losses.last().expect("one loss"));
    let grad_diff = run.grad_diff;
    println!(
        "{n} cells, {steps} upwind steps (Courant ≤ {:.2}), {iterations} iterations of gradient descent",
        run.u.iter().fold(0.0f64, |m, v| m.max(v.abs())) * scene.params.dt / scene.grid.dx
    );
    println!("loss {loss_initial:.6e} → {loss_final:.6e}");
    println!(
        "monolithic op: {} nodes, {} bytes peak per tape, {:.3} ms per iteration",
        run.nodes.0,
        run.peak_bytes.0,
        1e3 * op_time / iterations as f64
    );
    println!(
        "primitives:    {} nodes, {} bytes peak per tape, {:.3} ms per iteration",
        run.nodes.1,
        run.peak_bytes.1,
        1e3 * primitives_time / iterations as f64
    );
    println!(
        "primitives / op: {memory_ratio:.2}× the tape bytes, {time_ratio:.2}× the time; \
         max |gradient difference| over all iterates {grad_diff:.2e} (max |gradient| {:.2e})",
        run.grad_max
    );
    for f in write_charts(&args.out, &scene, &run)? {
        println!("wrote {}", f.display());
    }
    args.write_npy(&[
        ("d0", scene.d0.view(), "the initial density [n]"),
        ("target", scene.target.view(), "the target density [n]"),
        (
            "u_final",
            run.u.view(),
            "the velocity after gradient descent [n]",
        ),
        (
            "d_final",
            run.final_density.view(),
            "the density the final velocity carries d0 to [n]",
        ),
        (
            "grad_u_last",
            run.grad.view(),
            "the loss gradient in u at the last step taken [n]",
        ),
    ])?;
    if grad_diff > 1e-10 {
        return Err(format!("op and primitive gradients differ by {grad_diff:e} > 1e-10").into());
    }
    if loss_final >= loss_initial {
        return Err(format!(
            "gradient descent did not reduce the loss: {loss_initial} → {loss_final}"
        )
        .into());
    }
    common::print_json_line(&serde_json::json!({
        "example": "advection_inverse",
        "loss_initial": loss_initial,
        "loss_final": loss_final,
        "iterations": iterations,
        "grad_max_abs_diff_op_vs_primitives": grad_diff,
        "tape_bytes_op": run.peak_bytes.0,
        "tape_bytes_primitives": run.peak_bytes.1,
        "step_time_ratio_primitives_over_op": time_ratio,
    }));
    Ok(())
}
