//! The differentiate-pressure scene of PhiFlow's demo of the same name: find an
//! initial velocity in the left half of a closed box whose pressure projection
//! produces a target jet in the right half.
//!
//! 80 × 64 cells, dx = 1, closed walls (x-faces 81 × 64, y-faces 80 × 65, the wall faces closed).
//! LEFT = faces with x ≤ 40, RIGHT = faces with x ≥ 40 (the faces at x = 40
//! belong to both). The target is RIGHT · (0, 2·exp(−|p − (50, 10)|²/(2·32²)))
//! at the face centres. The velocity `v` starts as seeded smooth noise × 0.1 ×
//! LEFT; the loss is `½ Σ ((project(v·LEFT) − target)·RIGHT)²`, the projection's
//! pressure solve is CG to relative tolerance 1e-5, differentiated implicitly
//! (one adjoint CG solve per step), and `v` follows plain gradient descent with
//! step 1 for 30 iterations. Both solves are warm-started from the previous
//! step's solutions, as PhiFlow warm-starts its pressure.
//!
//! The first gradient is also computed exactly (sparse Cholesky in f64) and the
//! relative error reported. Tutorial: docs/03-implicit-gradients.md. Run:
//! `cargo run --release --example differentiate_pressure`
//! (`-- --small` or `-- --iterations N` for fewer iterations, `-- --out DIR`,
//! `-- --preconditioner multigrid` for multigrid-preconditioned CG in both
//! pressure solves instead of plain CG, `none`).

mod common;

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use diffphys::ops::cg::CgParams;
use diffphys::ops::mac::MacGrid;
use diffphys::ops::poisson::{SolveLog, WarmStart};
use diffphys::ops::projection::{max_abs_divergence, PressureProjection, ProjectionOp};
use diffphys::ops::reference::SparseCholesky;
use diffphys::prelude::*;
use diffphys::report::chart::{heatmap_svg, line_chart_svg, quiver_svg, LineChart, Series};
use ndarray::{Array2, Ix2, Zip};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

type BoxError = Box<dyn std::error::Error>;

/// A field on x-faces and one on y-faces.
#[derive(Debug, Clone)]
struct Faces {
    x: ArrayD<f64>,
    y: ArrayD<f64>,
}

impl Faces {
    fn zip(&self, other: &Faces, f: impl Fn(f64, f64) -> f64 + Copy) -> Faces {
        Faces {
            x: Zip::from(&self.x)
                .and(&other.x)
                .map_collect(|&a, &b| f(a, b)),
            y: Zip::from(&self.y)
                .and(&other.y)
                .map_collect(|&a, &b| f(a, b)),
        }
    }
}

/// The scene's fixed data.
struct Scene {
    mac: MacGrid,
    left: Faces,
    right: Faces,
    target: Faces,
}

impl Scene {
    fn new() -> Result<Self, BoxError> {
        let mac = MacGrid::new(Grid2::new(80, 64, 1.0, 1.0, Boundary::Closed)?);
        // the wall faces are closed: no velocity, no target, no control there
        let open = mac.open_faces_x().mapv(|o| f64::from(u8::from(o)));
        let open_y = mac.open_faces_y().mapv(|o| f64::from(u8::from(o)));
        let indicator = |keep: fn(f64) -> bool| Faces {
            x: mac.sample_x(|c| f64::from(u8::from(keep(c[0])))) * &open,
            y: mac.sample_y(|c| f64::from(u8::from(keep(c[0])))) * &open_y,
        };
        let left = indicator(|x| x <= 40.0);
        let right = indicator(|x| x >= 40.0);
        let jet = |c: [f64; 2]| {
            let r2 = (c[0] - 50.0).powi(2) + (c[1] - 10.0).powi(2);
            2.0 * (-r2 / (2.0 * 32.0 * 32.0)).exp()
        };
        let target = Faces {
            x: mac.sample_x(|_| 0.0),
            y: mac.sample_y(jet) * &right.y,
        };
        Ok(Scene {
            mac,
            left,
            right,
            target,
        })
    }

    /// Seeded smooth noise × 0.1 × LEFT (one [`SmoothNoise`] per component).
    fn initial_velocity(&self, seed: u64) -> Faces {
        let mut rng = StdRng::seed_from_u64(seed);
        let (nx, ny) = (SmoothNoise::new(&mut rng), SmoothNoise::new(&mut rng));
        let x = nx.normalised(self.mac.sample_x(|c| nx.value(c)), &self.mac.open_faces_x());
        let y = ny.normalised(self.mac.sample_y(|c| ny.value(c)), &self.mac.open_faces_y());
        Faces { x, y }.zip(&self.left, |v, l| 0.1 * v * l)
    }
}

/// A smooth random field on the 80 × 64 box: the 36 lowest Fourier modes with
/// random amplitudes (decaying as 1/|k|) and phases.
struct SmoothNoise {
    /// `(k, l, amplitude, phase x, phase y)`.
    modes: Vec<[f64; 5]>,
}

impl SmoothNoise {
    fn new(rng: &mut StdRng) -> Self {
        let mut modes = Vec::new();
        for k in 1..=6 {
            for l in 1..=6 {
                let (k, l) = (f64::from(k), f64::from(l));
                let amp = rng.random_range(-1.0..1.0) / (k * k + l * l).sqrt();
                modes.push([
                    k,
                    l,
                    amp,
                    rng.random_range(0.0..1.0),
                    rng.random_range(0.0..1.0),
                ]);
            }
        }
        SmoothNoise { modes }
    }

    fn value(&self, c: [f64; 2]) -> f64 {
        let tau = std::f64::consts::TAU;
        self.modes
            .iter()
            .map(|&[k, l, a, px, py]| {
                a * (tau * (k * c[0] / 80.0 + px)).sin() * (tau * (l * c[1] / 64.0 + py)).sin()
            })
            .sum()
    }

    /// `field` shifted and scaled to zero mean and unit standard deviation
    /// over the `open` faces, zero on the closed ones.
    fn normalised(&self, field: ArrayD<f64>, open: &ArrayD<bool>) -> ArrayD<f64> {
        let on_open = || field.iter().zip(open).filter(|(_, &o)| o).map(|(&v, _)| v);
        let n = on_open().count().max(1) as f64;
        let mean = on_open().sum::<f64>() / n;
        let std = (on_open().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
        Zip::from(&field)
            .and(open)
            .map_collect(|&v, &o| if o { (v - mean) / std } else { 0.0 })
    }
}

/// What one gradient step measured.
struct Step {
    loss: f64,
    grad: Faces,
    projected: Faces,
    pressure: ArrayD<f64>,
    seconds: f64,
}

/// The loss and its gradient with respect to `v` on a fresh tape.
fn gradient_step(scene: &Scene, op: ProjectionOp<f64>, v: &Faces) -> Result<Step, BoxError> {
    let start = Instant::now();
    let tape = Tape::<f64>::new();
    let (vx, vy) = (tape.var(v.x.clone()), tape.var(v.y.clone()));
    let ux = vx.mul(tape.constant(scene.left.x.clone()))?;
    let uy = vy.mul(tape.constant(scene.left.y.clone()))?;
    let out = tape.apply_multi(op, &[ux, uy])?; // [u'_x, u'_y, p]
    let (px, py, pressure) = (out[0], out[1], out[2]);
    let ex = px
        .sub(tape.constant(scene.target.x.clone()))?
        .mul(tape.constant(scene.right.x.clone()))?;
    let ey = py
        .sub(tape.constant(scene.target.y.clone()))?
        .mul(tape.constant(scene.right.y.clone()))?;
    let loss = ex
        .mul(ex)?
        .sum()?
        .add(ey.mul(ey)?.sum()?)?
        .mul_scalar(0.5)?;
    let grads = tape.backward(loss, &[vx, vy])?;
    let seconds = start.elapsed().as_secs_f64();
    let missing = || "missing gradient".to_string();
    Ok(Step {
        loss: loss.item()?,
        grad: Faces {
            x: grads.get(vx).ok_or_else(missing)?.clone(),
            y: grads.get(vy).ok_or_else(missing)?.clone(),
        },
        projected: Faces {
            x: px.to_array(),
            y: py.to_array(),
        },
        pressure: pressure.to_array(),
        seconds,
    })
}

/// The same gradient with exact solves (sparse Cholesky, f64), following the
/// adjoint of docs/03: `g_u' = RIGHT ⊙ (u' − t)`, `s = S(−D g_u')`,
/// `∂L/∂v = LEFT ⊙ (g_u' − G s)`.
fn exact_gradient(scene: &Scene, v: &Faces) -> Result<Faces, BoxError> {
    let mac = &scene.mac;
    let chol = SparseCholesky::new(&mac.pressure_operator(), mac.null_space())?;
    let u = v.zip(&scene.left, |a, b| a * b);
    let p = chol.solve(mac.divergence(u.x.view(), u.y.view())?.mapv(|d| -d).view())?;
    let (gx, gy) = mac.gradient(p.view())?;
    let projected = Faces {
        x: &u.x - &gx,
        y: &u.y - &gy,
    };
    let g_out = projected
        .zip(&scene.target, |a, t| a - t)
        .zip(&scene.right, |e, r| e * r * r);
    let s = chol.solve(
        mac.divergence(g_out.x.view(), g_out.y.view())?
            .mapv(|d| -d)
            .view(),
    )?;
    let (sx, sy) = mac.gradient(s.view())?;
    let g = Faces {
        x: &g_out.x - &sx,
        y: &g_out.y - &sy,
    };
    Ok(g.zip(&scene.left, |a, b| a * b))
}

fn rel_error(a: &Faces, b: &Faces) -> f64 {
    let sq = |x: &ArrayD<f64>| x.iter().map(|v| v * v).sum::<f64>();
    let diff = sq(&(&a.x - &b.x)) + sq(&(&a.y - &b.y));
    (diff / (sq(&b.x) + sq(&b.y))).sqrt()
}

/// Face velocities averaged to cell centres (cell `i` lies between faces `i`
/// and `i + 1`; the wall faces are closed, zero).
fn to_cells(scene: &Scene, f: &Faces) -> Result<(Array2<f64>, Array2<f64>), BoxError> {
    let [nx, ny] = scene.mac.cell_shape();
    let fx = f.x.view().into_dimensionality::<Ix2>()?;
    let fy = f.y.view().into_dimensionality::<Ix2>()?;
    let u = Array2::from_shape_fn((nx, ny), |(i, j)| 0.5 * (fx[[i, j]] + fx[[i + 1, j]]));
    let v = Array2::from_shape_fn((nx, ny), |(i, j)| 0.5 * (fy[[i, j]] + fy[[i, j + 1]]));
    Ok((u, v))
}

fn write_charts(
    out: &Path,
    scene: &Scene,
    last: &Step,
    first_grad: &Faces,
    losses: &[f64],
) -> Result<(), BoxError> {
    let (u, v) = to_cells(scene, &last.projected)?;
    quiver_svg(
        &out.join("velocity.svg"),
        "Final projected velocity project(v·LEFT)",
        u.view(),
        v.view(),
    )?;
    let vy = last.projected.y.view().into_dimensionality::<Ix2>()?;
    heatmap_svg(
        &out.join("velocity_y.svg"),
        "Final projected y-velocity (y-faces)",
        vy,
    )?;
    let gy = first_grad.y.view().into_dimensionality::<Ix2>()?;
    heatmap_svg(
        &out.join("gradient_y.svg"),
        "dL/dv_y at the first iteration (y-faces)",
        gy,
    )?;
    let (gu, gv) = to_cells(scene, first_grad)?;
    quiver_svg(
        &out.join("gradient.svg"),
        "dL/dv at the first iteration",
        gu.view(),
        gv.view(),
    )?;
    let points = losses
        .iter()
        .enumerate()
        .map(|(i, &l)| (i as f64, l))
        .collect();
    line_chart_svg(
        &out.join("loss.svg"),
        &LineChart {
            title: "differentiate_pressure: loss per gradient-descent iteration",
            x_label: "iteration",
            y_label: "loss",
            log_x: false,
            log_y: true,
            series: &[Series::new("implicit CG gradient", points)],
        },
    )?;
    Ok(())
}

/// Finds an initial velocity whose pressure projection produces a target jet
/// (PhiFlow's differentiate-pressure demo).
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    /// The CG solves' preconditioner.
    #[arg(long, value_enum, default_value_t = Preconditioner::None)]
    preconditioner: Preconditioner,
    /// Gradient-descent iterations (5 with --small).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 30,
        default_value_if("small", "true", "5")
    )]
    iterations: usize,
}

#[derive(Clone, Copy, PartialEq, clap::ValueEnum)]
enum Preconditioner {
    /// Plain CG.
    None,
    /// Multigrid-preconditioned CG.
    Multigrid,
}

fn main() -> Result<(), BoxError> {
    let Cli {
        common: args,
        preconditioner,
        iterations,
    } = common::parse_args("differentiate_pressure")?;
    let multigrid = preconditioner == Preconditioner::Multigrid;
    let scene = Scene::new()?;
    let mut projection =
        PressureProjection::new(scene.mac.clone(), CgParams::default().with_rel_tol(1e-5));
    if multigrid {
        // One V(2,2) cycle per CG iteration, forward and adjoint.
        projection = projection.with_multigrid(2)?;
    }
    let projection = Arc::new(projection);
    let preconditioner = if multigrid { "multigrid" } else { "none" };
    println!("pressure solves: CG, preconditioner {preconditioner}");
    let log = SolveLog::<f64>::new();
    let op = ProjectionOp::new(Arc::clone(&projection))
        .with_warm_start(WarmStart::both())
        .with_log(log.clone());

    let mut v = scene.initial_velocity(42);
    let exact = exact_gradient(&scene, &v)?;
    let mut losses = Vec::with_capacity(iterations);
    let mut seconds = 0.0;
    let mut first_grad = None;
    let mut last = None;
    println!("iteration        loss   CG fwd  CG adj   seconds");
    for it in 0..iterations {
        let step = gradient_step(&scene, op.clone(), &v)?;
        let (fwd, adj) = (log.last_forward(), log.last_adjoint());
        println!(
            "{it:>9} {:>11.6} {:>8} {:>7} {:>9.5}",
            step.loss,
            fwd.map_or(0, |i| i.iterations),
            adj.map_or(0, |i| i.iterations),
            step.seconds
        );
        losses.push(step.loss);
        seconds += step.seconds;
        v = v.zip(&step.grad, |a, g| a - g);
        first_grad.get_or_insert_with(|| step.grad.clone());
        last = Some(step);
    }
    let (Some(first_grad), Some(last)) = (first_grad, last) else {
        return Err("--iterations must be at least 1".into());
    };
    let grad_error = rel_error(&first_grad, &exact);
    let divergence =
        max_abs_divergence(&scene.mac, last.projected.x.view(), last.projected.y.view())?;
    let steps = iterations as f64;
    let per_step = |total: usize| (total as f64 / steps * 10.0).round() / 10.0;
    println!(
        "first gradient vs exact (sparse Cholesky): relative error {grad_error:.3e}; \
         max |div u'| = {divergence:.3e}; {:.4} s per gradient step; \
         CG iterations per step: forward {}, adjoint {}",
        seconds / steps,
        per_step(log.forward_iterations()),
        per_step(log.adjoint_iterations())
    );
    write_charts(&args.out, &scene, &last, &first_grad, &losses)?;
    println!("charts written to {}", args.out.display());
    args.write_npy(&[
        (
            "v_final_x",
            v.x.view(),
            "the optimised velocity, x-faces [81, 64]",
        ),
        (
            "v_final_y",
            v.y.view(),
            "the optimised velocity, y-faces [80, 63]",
        ),
        (
            "target_x",
            scene.target.x.view(),
            "the target velocity, x-faces",
        ),
        (
            "target_y",
            scene.target.y.view(),
            "the target velocity, y-faces",
        ),
        (
            "projected_x",
            last.projected.x.view(),
            "the projected velocity of the last step, x-faces",
        ),
        (
            "projected_y",
            last.projected.y.view(),
            "the projected velocity of the last step, y-faces",
        ),
        (
            "pressure",
            last.pressure.view(),
            "the pressure of the last step's projection [80, 64]",
        ),
        (
            "grad_x_last",
            last.grad.x.view(),
            "the loss gradient of the last step, x-faces",
        ),
        (
            "grad_y_last",
            last.grad.y.view(),
            "the loss gradient of the last step, y-faces",
        ),
        (
            "grad_x_exact_first",
            exact.x.view(),
            "the first gradient by sparse Cholesky, x-faces",
        ),
        (
            "grad_y_exact_first",
            exact.y.view(),
            "the first gradient by sparse Cholesky, y-faces",
        ),
    ])?;
    common::print_json_line(&serde_json::json!({
        "example": "differentiate_pressure",
        "preconditioner": preconditioner,
        "losses": losses,
        "max_abs_divergence": divergence,
        "seconds_per_gradient_step": seconds / steps,
        "cg_iterations_forward": per_step(log.forward_iterations()),
        "cg_iterations_adjoint": per_step(log.adjoint_iterations()),
        "gradient_rel_error_vs_exact": grad_error,
    }));
    Ok(())
}
