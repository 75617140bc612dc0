//! The flow step's speed and memory on the scenes its peers are measured on:
//! forward and forward + backward per step, the backward/forward ratio, the
//! pressure iterations per step and the tape's bytes per step.
//!
//! - **wake**: the PBDL book's wake flow as PhiFlow runs it, in our terms: a
//!   100 × 200 domain of `R × 2R` cells, uniform inflow 1 at the bottom,
//!   outflow at the top, no-slip walls left and right, a cylinder of radius 10
//!   at (50, 50), explicit viscosity ν = 1.25e-3 (the book's Re = 500 at its
//!   resolution factor 32), semi-Lagrangian advection, dt = 1; the state is
//!   the uniform start advanced 40 steps, as on PhiFlow's side.
//! - **box**: the periodic Taylor–Green box [0, 2π]² of JAX-CFD's anchor,
//!   ν = 1e-3, dt = 0.5 h (Courant 0.5 at |u| = 1), MacCormack advection with
//!   the limiter (second order, as JAX-CFD's van Leer scheme).
//!
//! Forward: a rollout of `steps` steps without a tape (`Scene::forward`).
//! Forward + backward: the same rollout on a tape and the gradient of
//! `½ |u_final|²` with respect to the initial velocity (the implicit pressure
//! adjoint). Times are per step, best of the repetitions after two warm-up runs.
//!
//! `cargo run --release --example flow_step [-- --small] [--out DIR] [--f64]`
//! prints a table and ends with one JSON line; `--serve --scene wake|box --res N
//! --steps S [--f64] [--solver cholesky|cg|mgpcg]` speaks the line protocol of
//! `benches/flow_peers/worker_protocol.md` for `benches/flow_peers/run.py`.

mod common;
mod flow_common;

use std::io::BufRead;
use std::time::Instant;

use diffphys::flow::{FlowState, FlowVars, ParamVars, PressureSolver, Scene};
use diffphys::tape::{Real, Tape};
use serde_json::json;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

#[derive(Debug, Clone, Copy, PartialEq, clap::ValueEnum)]
enum SceneKind {
    /// PhiFlow's wake flow.
    Wake,
    /// JAX-CFD's periodic Taylor–Green box.
    Box,
}

#[derive(Debug, Clone, Copy, PartialEq, clap::ValueEnum)]
enum Solver {
    /// The scene's default (the fastest at these sizes).
    Default,
    /// Sparse Cholesky.
    Cholesky,
    /// CG to a relative residual of 1e-3.
    Cg,
    /// Multigrid-preconditioned CG to a relative residual of 1e-3.
    #[value(name = "mgpcg")]
    MgPcg,
}

impl Solver {
    fn pressure(self) -> Option<PressureSolver> {
        // the peers' tolerance: PhiFlow's CG to a relative residual of 1e-3
        match self {
            Solver::Default => None,
            Solver::Cholesky => Some(PressureSolver::Cholesky),
            Solver::Cg => Some(PressureSolver::Cg {
                rel_tol: 1e-3,
                max_iters: 5000,
            }),
            Solver::MgPcg => Some(PressureSolver::MultigridCg {
                rel_tol: 1e-3,
                max_iters: 500,
                sweeps: 2,
            }),
        }
    }
}

/// A scene, its start state, and the rollout length.
struct Bench<T: Real> {
    res: usize,
    scene: Scene,
    start: FlowState<T>,
    steps: usize,
}

impl<T: Real> Bench<T> {
    fn new(kind: SceneKind, res: usize, steps: usize, solver: Solver) -> Result<Self> {
        let (scene, start) = match kind {
            SceneKind::Wake => {
                let scene = flow_common::wake_scene(res, solver.pressure())?;
                let start = flow_common::wake_start(&scene)?;
                (scene, start)
            }
            SceneKind::Box => flow_common::box_scene(res, solver.pressure())?,
        };
        Ok(Bench {
            res,
            scene,
            start,
            steps,
        })
    }

    fn cells(&self) -> usize {
        self.scene.grid().nx * self.scene.grid().ny
    }

    fn resolution(&self) -> String {
        format!("{}x{}", self.scene.grid().nx, self.scene.grid().ny)
    }

    /// The forward rollout: seconds and the pressure iterations of each step.
    fn forward(&self) -> Result<(f64, Vec<usize>)> {
        let p = self.scene.params();
        let t = Instant::now();
        let mut s = self.start.clone();
        let mut iterations = Vec::with_capacity(self.steps);
        for _ in 0..self.steps {
            let (next, info) = self.scene.forward(&s, &p)?;
            iterations.push(info.pressure_iterations.iter().sum());
            s = next;
        }
        Ok((t.elapsed().as_secs_f64(), iterations))
    }

    /// The rollout on a tape and the gradient of `½|u|²` at its end with
    /// respect to the start velocity: seconds, the tape's peak bytes, the
    /// gradient's norm.
    fn forward_backward(&self) -> Result<(f64, usize, f64)> {
        let t = Instant::now();
        let tape = Tape::<T>::new();
        let start = FlowVars::variables(&tape, &self.start);
        let params = ParamVars::constants(&tape, &self.scene.params());
        let mut s = start.clone();
        for _ in 0..self.steps {
            s = self.scene.step(&tape, &s, &params)?.0;
        }
        let energy = s.ux.dot(s.ux)?.add(s.uy.dot(s.uy)?)?;
        let loss = energy.mul_scalar(T::from_f64(0.5))?;
        let grads = tape.backward(loss, &[start.ux, start.uy])?;
        let seconds = t.elapsed().as_secs_f64();
        let norm = [start.ux, start.uy]
            .iter()
            .filter_map(|v| grads.get(*v))
            .flat_map(|g| g.iter().map(|x| x.as_f64().powi(2)).collect::<Vec<_>>())
            .sum::<f64>()
            .sqrt();
        Ok((seconds, tape.stats().peak_bytes, norm))
    }
}

/// CPU seconds of every thread of this process (`/proc/self/task/*/schedstat`),
/// or 0 where the kernel does not say.
fn cpu_seconds() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0.0;
    };
    tasks
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .sum::<f64>()
        * 1e-9
}

/// `--serve`: the worker of benches/flow_peers/run.py.
fn serve<T: Real>(
    kind: SceneKind,
    res: usize,
    steps: usize,
    solver: Solver,
    precision: &str,
) -> Result<()> {
    let bench = Bench::<T>::new(kind, res, steps, solver)?;
    let mut iterations = Vec::new();
    let mut tape_bytes = 0;
    let mut grad_norm = 0.0;
    for _ in 0..2 {
        iterations = bench.forward()?.1;
        (_, tape_bytes, grad_norm) = bench.forward_backward()?;
    }
    println!(
        "{}",
        json!({
            "ready": true, "tool": "diffphys", "scene": if kind == SceneKind::Wake { "wake" } else { "periodic Taylor-Green box" },
            "resolution": bench.resolution(), "cells": bench.cells(), "precision": precision, "steps": steps,
            "solver": format!("{:?}", bench.scene.settings().pressure_solver),
            "advection": format!("{:?}", bench.scene.settings().advection),
            "pressure_iterations_per_step": iterations, "tape_peak_bytes_per_step": tape_bytes / steps,
            "grad_norm": grad_norm, "threads": rayon_threads(),
        })
    );
    for line in std::io::stdin().lock().lines() {
        let line = line?;
        let (t, c) = (Instant::now(), cpu_seconds());
        match line.trim() {
            "fwd" => {
                bench.forward()?;
            }
            "fwdbwd" => {
                bench.forward_backward()?;
            }
            "quit" => break,
            other => return Err(format!("unknown command {other:?}").into()),
        }
        println!(
            "{}",
            json!({"what": line.trim(), "seconds": t.elapsed().as_secs_f64(), "cpu_seconds": cpu_seconds() - c})
        );
    }
    println!("{}", json!({"done": true}));
    Ok(())
}

fn rayon_threads() -> Option<usize> {
    std::env::var("RAYON_NUM_THREADS").ok()?.parse().ok()
}

/// One row of the table: best-of-`repeats` per-step times and the rest.
fn measure<T: Real>(
    kind: SceneKind,
    res: usize,
    steps: usize,
    repeats: usize,
) -> Result<serde_json::Value> {
    let bench = Bench::<T>::new(kind, res, steps, Solver::Default)?;
    let (mut fwd, mut fwdbwd) = (f64::INFINITY, f64::INFINITY);
    let (mut iterations, mut bytes, mut norm) = (Vec::new(), 0, 0.0);
    for _ in 0..repeats + 1 {
        let (t, it) = bench.forward()?;
        fwd = fwd.min(t);
        iterations = it;
        let (t, b, n) = bench.forward_backward()?;
        fwdbwd = fwdbwd.min(t);
        (bytes, norm) = (b, n);
    }
    let per = |t: f64| t / steps as f64 * 1e3;
    let row = json!({
        "scene": if kind == SceneKind::Wake { "wake" } else { "box" },
        "resolution": bench.resolution(), "res": bench.res, "cells": bench.cells(), "steps": steps,
        "solver": format!("{:?}", bench.scene.settings().pressure_solver),
        "forward_ms_per_step": per(fwd), "forward_backward_ms_per_step": per(fwdbwd),
        "backward_over_forward": (fwdbwd - fwd) / fwd,
        "pressure_iterations_per_step": iterations, "tape_bytes_per_step": bytes / steps, "grad_norm": norm,
    });
    println!(
        "{:>5} {:>9}  fwd {:9.3} ms/step  fwd+bwd {:9.3} ms/step  bwd/fwd {:5.2}  tape {:7.2} MB/step  pressure its {:?}",
        row["scene"].as_str().unwrap_or(""),
        bench.resolution(),
        per(fwd),
        per(fwdbwd),
        (fwdbwd - fwd) / fwd,
        (bytes / steps) as f64 / 1e6,
        &iterations[..iterations.len().min(3)],
    );
    Ok(row)
}

fn run_table<T: Real>(args: &common::ExampleArgs, precision: &str) -> Result<()> {
    let wake: &[usize] = args.pick(&[32, 128, 512], &[32]);
    let boxes: &[usize] = args.pick(&[64, 128, 256], &[64]);
    let (steps, repeats) = args.pick((20, 5), (4, 1));
    println!(
        "flow step, {precision}, RAYON_NUM_THREADS={:?}, best of {repeats} after a warm-up run",
        rayon_threads()
    );
    let mut rows = Vec::new();
    for &r in wake {
        rows.push(measure::<T>(SceneKind::Wake, r, steps, repeats)?);
    }
    for &n in boxes {
        rows.push(measure::<T>(SceneKind::Box, n, steps, repeats)?);
    }
    write_chart(&args.out.join("flow_step.svg"), &rows)?;
    common::print_json_line(&json!({
        "precision": precision, "rayon_num_threads": rayon_threads(), "steps": steps,
        "repeats": repeats, "rows": rows, "peak_rss_bytes": flow_common::peak_rss_bytes(),
    }));
    Ok(())
}

/// Bars of forward and forward + backward ms per step, one pair per row.
fn write_chart(path: &std::path::Path, rows: &[serde_json::Value]) -> Result<()> {
    use plotters::prelude::*;
    let labels: Vec<String> = rows
        .iter()
        .map(|r| {
            format!(
                "{} {}",
                r["scene"].as_str().unwrap_or(""),
                r["resolution"].as_str().unwrap_or("")
            )
        })
        .collect();
    let value = |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap_or(0.0).max(1e-3);
    let top = rows
        .iter()
        .map(|r| value(r, "forward_backward_ms_per_step"))
        .fold(1.0f64, f64::max);
    let root = SVGBackend::new(path, (760, 420)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "flow step: ms per step (log), forward and forward + backward",
            ("sans-serif", 16),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..rows.len() as f64, (1e-3..top * 2.0).log_scale())?;
    chart
        .configure_mesh()
        .x_labels(rows.len())
        .x_label_formatter(&|x| labels.get(x.floor() as usize).cloned().unwrap_or_default())
        .y_desc("ms per step")
        .draw()?;
    for (i, r) in rows.iter().enumerate() {
        let x = i as f64;
        chart.draw_series([
            Rectangle::new(
                [(x + 0.1, 1e-3), (x + 0.45, value(r, "forward_ms_per_step"))],
                BLUE.filled(),
            ),
            Rectangle::new(
                [
                    (x + 0.55, 1e-3),
                    (x + 0.9, value(r, "forward_backward_ms_per_step")),
                ],
                RED.filled(),
            ),
        ])?;
    }
    root.present()?;
    Ok(())
}

/// The flow step's speed and memory on the wake and box scenes, or with
/// `--serve`, the peers' benchmark worker.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    /// In f64 (f32 otherwise).
    #[arg(long)]
    f64: bool,
    /// Speak the line protocol of benches/flow_peers/worker_protocol.md instead
    /// of printing the table.
    #[arg(long)]
    serve: bool,
    /// With --serve: the scene.
    #[arg(long, value_enum, default_value_t = SceneKind::Wake)]
    scene: SceneKind,
    /// With --serve: the resolution factor (wake) or cells per side (box).
    #[arg(long, value_name = "N", default_value_t = 32)]
    res: usize,
    /// With --serve: steps per rollout.
    #[arg(long, value_name = "N", default_value_t = 20)]
    steps: usize,
    /// With --serve: the pressure solver.
    #[arg(long, value_enum, default_value_t = Solver::Default)]
    solver: Solver,
}

fn main() -> Result<()> {
    let cli: Cli = common::parse_args("flow_step")?;
    let precision = if cli.f64 { "f64" } else { "f32" };
    match (cli.serve, cli.f64) {
        (true, true) => serve::<f64>(cli.scene, cli.res, cli.steps, cli.solver, precision),
        (true, false) => serve::<f32>(cli.scene, cli.res, cli.steps, cli.solver, precision),
        (false, true) => run_table::<f64>(&cli.common, precision),
        (false, false) => run_table::<f32>(&cli.common, precision),
    }
}
