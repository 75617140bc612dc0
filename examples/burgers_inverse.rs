//! The Burgers reconstruction scene of the Physics-based Deep Learning book
//! ("Burgers optimization with a differentiable physics gradient"): find the
//! initial state of a viscous Burgers simulation from its state at t = 0.5.
//!
//! 1D periodic domain [−1, 1], 128 cells, 32 steps of dt = 1/32, ν = 0.01/(128π).
//! Each step is explicit diffusion `u + ν·dt·∇²u`, then semi-Lagrangian
//! self-advection of the diffused state (the diffused state is both the advected
//! field and the velocity of the backtrace) with linear interpolation. The unknown
//! is the initial state, starting from zero; the loss is the mean squared
//! difference between the state after step 16 and the reference of
//! `data/burgers_t16_reference.json` (in the repository); plain gradient descent with
//! learning rate 5.
//!
//! Tutorial: docs/02-advection-inverse-problems.md. Run:
//! `cargo run --release --example burgers_inverse` (`-- --small` for 5 iterations).

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use diffphys::ops::advection::{semi_lagrangian1, SemiLagrangian1};
use diffphys::ops::stencil::{DiffusionParams, ExplicitDiffusion1};
use diffphys::ops::tape_ops::LinearOp;
use diffphys::prelude::*;
use diffphys::report::chart::{heatmap_svg_with_axes, line_chart_svg, LineChart, Series};
use ndarray::{Array1, Array2, Ix1};

type BoxError = Box<dyn std::error::Error>;

/// Cells, time step, steps, the step the loss looks at, learning rate.
const N: usize = 128;
const STEPS: usize = 32;
const LOSS_STEP: usize = 16;
const LEARNING_RATE: f64 = 5.0;
/// The losses the book prints at iterations 0 to 4.
const PUBLISHED: [f64; 5] = [0.382915, 0.326882, 0.281032, 0.242804, 0.210666];

/// The simulation and its target.
struct Burgers {
    grid: Grid1,
    dt: f64,
    diffusion: Arc<ExplicitDiffusion1>,
    target: ArrayD<f64>,
}

impl Burgers {
    fn new(target: Array1<f64>) -> Result<Self, BoxError> {
        let grid = Grid1::over(-1.0, 1.0, N, Boundary::Periodic)?;
        let dt = 1.0 / STEPS as f64;
        let nu = 0.01 / (N as f64 * std::f64::consts::PI);
        let diffusion = ExplicitDiffusion1::new(grid, DiffusionParams::new(nu, dt))?;
        Ok(Burgers {
            grid,
            dt,
            diffusion: Arc::new(diffusion),
            target: target.into_dyn(),
        })
    }

    /// One step on the tape: diffuse, then advect the diffused state by itself.
    fn step<'t>(&self, u: Var<'t, f64>) -> Result<Var<'t, f64>, BoxError> {
        let tape = u.tape();
        let diffused = tape.apply(LinearOp::new(Arc::clone(&self.diffusion)), &[u])?;
        let advect = SemiLagrangian1::new(self.grid, self.dt);
        Ok(tape.apply(advect, &[diffused, diffused])?)
    }

    /// The loss `mean((u₁₆ − target)²)` and its gradient with respect to `u₀`.
    fn loss_and_gradient(&self, u0: &ArrayD<f64>) -> Result<(f64, ArrayD<f64>), BoxError> {
        let tape = Tape::<f64>::new();
        let x = tape.var(u0.clone());
        let mut u = x;
        for _ in 0..LOSS_STEP {
            u = self.step(u)?;
        }
        let loss = u.sub(tape.constant(self.target.clone()))?.powi(2)?.mean()?;
        let mut grads = tape.backward(loss, &[x])?;
        let g = grads.take(x).ok_or("no gradient for the initial state")?;
        Ok((loss.item()?, g))
    }

    /// All 33 states from `u0`, as rows of a `[STEPS + 1, N]` array, without a tape.
    fn trajectory(&self, u0: &ArrayD<f64>) -> Result<Array2<f64>, BoxError> {
        let mut out = Array2::zeros((STEPS + 1, N));
        let mut u = u0.clone().into_dimensionality::<Ix1>()?;
        out.row_mut(0).assign(&u);
        for t in 1..=STEPS {
            let diffused = self
                .diffusion
                .apply(u.view().into_dyn())?
                .into_dimensionality::<Ix1>()?;
            u = semi_lagrangian1(&self.grid, self.dt, diffused.view(), diffused.view())?;
            out.row_mut(t).assign(&u);
        }
        Ok(out)
    }
}

/// The reference state at t = 0.5, from `data/` in the repository.
fn load_reference() -> Result<Array1<f64>, BoxError> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/burgers_t16_reference.json");
    let text = std::fs::read_to_string(&path).map_err(|e| {
        format!(
            "cannot read the Burgers reference {}: {e} (it ships with the repository \
             as data/burgers_t16_reference.json)",
            path.display()
        )
    })?;
    let json: serde_json::Value = serde_json::from_str(&text)?;
    let values: Vec<f64> = json["values"]
        .as_array()
        .ok_or("reference JSON has no \"values\" array")?
        .iter()
        .map(|v| v.as_f64().ok_or("reference value is not a number"))
        .collect::<Result<_, _>>()?;
    if values.len() != N {
        return Err(format!("reference has {} values, expected {N}", values.len()).into());
    }
    Ok(Array1::from(values))
}

/// Writes the charts: reconstructed and true space-time fields, the loss curve,
/// and the states at t = 0 and t = 0.5 against their references.
fn write_charts(
    out: &Path,
    scene: &Burgers,
    u0: &ArrayD<f64>,
    losses: &[f64],
) -> Result<Vec<PathBuf>, BoxError> {
    let x = scene.grid.centers();
    let truth0 = Array1::from_iter(x.iter().map(|x| -(std::f64::consts::PI * x).sin())).into_dyn();
    let reconstructed = scene.trajectory(u0)?;
    let truth = scene.trajectory(&truth0)?;
    let mut files = Vec::new();
    let mut save = |name: &str| {
        let p = out.join(name);
        files.push(p.clone());
        p
    };
    heatmap_svg_with_axes(
        &save("burgers_reconstructed.svg"),
        "Burgers, reconstructed: u(t, x)",
        reconstructed.view(),
        ["time step (dt = 1/32)", "x (cell, x = -1 at 0)"],
    )?;
    heatmap_svg_with_axes(
        &save("burgers_reference.svg"),
        "Burgers from u0 = -sin(πx): u(t, x)",
        truth.view(),
        ["time step (dt = 1/32)", "x (cell, x = -1 at 0)"],
    )?;
    let loss_series = [Series::new(
        "loss",
        losses
            .iter()
            .enumerate()
            .map(|(i, &l)| (i as f64, l))
            .collect(),
    )];
    line_chart_svg(
        &save("burgers_loss.svg"),
        &LineChart {
            title: "Burgers reconstruction: loss per gradient-descent iteration",
            x_label: "iteration",
            y_label: "mean squared error at t = 0.5",
            log_x: false,
            log_y: true,
            series: &loss_series,
        },
    )?;
    let curve = |label: &str, v: ndarray::ArrayView1<'_, f64>| {
        Series::new(label, x.iter().copied().zip(v.iter().copied()).collect())
    };
    let states = [
        curve("reconstructed u(t=0.5)", reconstructed.row(LOSS_STEP)),
        curve(
            "reference u(t=0.5)",
            scene.target.view().into_dimensionality::<Ix1>()?,
        ),
        curve("reconstructed u(t=0)", reconstructed.row(0)),
        curve("-sin(pi x)", truth.row(0)),
    ];
    line_chart_svg(
        &save("burgers_states.svg"),
        &LineChart {
            title: "Burgers reconstruction: states at t = 0 and t = 0.5",
            x_label: "x",
            y_label: "u",
            log_x: false,
            log_y: false,
            series: &states,
        },
    )?;
    Ok(files)
}

/// Reconstructs the Burgers scene's initial state from its state at t = 0.5.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    /// Gradient-descent iterations (5 with --small).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 50,
        default_value_if("small", "true", "5")
    )]
    iterations: usize,
}

fn main() -> Result<(), BoxError> {
    let Cli {
        common: args,
        iterations,
    } = common::parse_args("burgers_inverse")?;
    let scene = Burgers::new(load_reference()?)?;

    let mut u0 = ArrayD::zeros(vec![N]);
    let mut losses = Vec::with_capacity(iterations);
    let mut last_grad = ArrayD::zeros(vec![N]);
    let start = Instant::now();
    for it in 0..iterations {
        let (loss, grad) = scene.loss_and_gradient(&u0)?;
        losses.push(loss);
        match PUBLISHED.get(it) {
            Some(p) => println!(
                "iteration {it:2}: loss {loss:.6} (published {p:.6}, {:+.3}%)",
                100.0 * (loss - p) / p
            ),
            None => println!("iteration {it:2}: loss {loss:.6}"),
        }
        u0.scaled_add(-LEARNING_RATE, &grad);
        last_grad = grad;
    }
    let seconds_per_iteration = start.elapsed().as_secs_f64() / iterations.max(1) as f64;
    let worst = losses
        .iter()
        .zip(PUBLISHED)
        .map(|(l, p)| ((l - p) / p).abs())
        .fold(0.0f64, f64::max);
    println!(
        "{} iterations, {:.2} ms each; largest deviation from the published losses {:.4}%",
        iterations,
        1e3 * seconds_per_iteration,
        100.0 * worst
    );
    for f in write_charts(&args.out, &scene, &u0, &losses)? {
        println!("wrote {}", f.display());
    }
    let trajectory = scene.trajectory(&u0)?.into_dyn();
    args.write_npy(&[
        (
            "u0_final",
            u0.view(),
            "the reconstructed initial state [128]",
        ),
        (
            "target_t16",
            scene.target.view(),
            "the reference state at step 16 [128]",
        ),
        (
            "trajectory",
            trajectory.view(),
            "all 33 states from u0_final [33, 128]",
        ),
        (
            "grad_u0_last",
            last_grad.view(),
            "the loss gradient of the last iteration [128]",
        ),
    ])?;
    if worst > 0.005 {
        return Err(format!(
            "losses deviate from the published ones by {:.3}% (> 0.5%)",
            100.0 * worst
        )
        .into());
    }
    common::print_json_line(&serde_json::json!({
        "example": "burgers_inverse",
        "losses": losses,
        "seconds_per_iteration": seconds_per_iteration,
    }));
    Ok(())
}
