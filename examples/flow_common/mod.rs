//! What the flow examples and `benches/flow.rs` share: the scenes the peers
//! are measured on, the per-step cost of a scene on and off the tape, a
//! heat-map chart of a field, and how a validation example reports its floors.

#![allow(dead_code)] // each example uses a different part

use std::time::Instant;

use diffphys::flow::validation::{all_met, FloorCheck};
use diffphys::flow::{
    Advection, FlowState, FlowVars, ParamVars, PressureSolver, Scene, TaylorGreen,
};
use diffphys::tape::{Real, Tape};
use ndarray::Array2;
use serde_json::{json, Value};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// The PBDL book's wake flow as PhiFlow runs it
/// ([`diffphys::flow::validation::pbdl_wake`]); `pressure` overrides the
/// scene's default solver.
pub fn wake_scene(res: usize, pressure: Option<PressureSolver>) -> Result<Scene> {
    let mut b = diffphys::flow::validation::pbdl_wake(res);
    if let Some(p) = pressure {
        b = b.pressure_solver(p);
    }
    Ok(b.build()?)
}

/// The wake's start state, as on PhiFlow's side: velocity 1 along the flow
/// everywhere, advanced 40 steps so the wake is developing.
pub fn wake_start<T: Real>(scene: &Scene) -> Result<FlowState<T>> {
    let g = scene.grid();
    let uy = Array2::from_elem(g.shape_y(), T::one());
    let mut s = FlowState::from_velocity(scene, Array2::zeros(g.shape_x()), uy);
    let p = scene.params();
    for _ in 0..40 {
        s = scene.forward(&s, &p)?.0;
    }
    Ok(s)
}

/// JAX-CFD's periodic Taylor–Green box [0, 2π]² at `n²` cells, ν = 1e-3,
/// dt = 0.5 h (Courant 0.5 at |u| = 1), MacCormack advection with the limiter
/// (second order, as JAX-CFD's van Leer scheme), and its start state.
pub fn box_scene<T: Real>(
    n: usize,
    pressure: Option<PressureSolver>,
) -> Result<(Scene, FlowState<T>)> {
    let tg = TaylorGreen {
        amplitude: 1.0,
        viscosity: 1e-3,
    };
    let h = 2.0 * std::f64::consts::PI / n as f64;
    let mut b = tg.scene(n, 0.5 * h, Advection::MacCormack { limiter: true });
    if let Some(p) = pressure {
        b = b.pressure_solver(p);
    }
    let scene = b.build()?;
    let start = tg.state(&scene, 0.0);
    Ok((scene, start))
}

/// Times `steps` steps of `scene` from `start` (f64, this process's threads):
/// without a tape, then on a tape with the gradient of `½|u_end|²` with
/// respect to the start velocity. Per-step milliseconds of each part, the
/// backward/forward ratio (backward sweep over the taped forward), the tape's
/// peak bytes per step.
pub fn step_costs(scene: &Scene, start: &FlowState<f64>, steps: usize) -> Result<Value> {
    let params = scene.params();
    let t = Instant::now();
    let mut s = start.clone();
    for _ in 0..steps {
        s = scene.forward(&s, &params)?.0;
    }
    let plain = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let tape = Tape::<f64>::new();
    let v0 = FlowVars::variables(&tape, start);
    let p = ParamVars::constants(&tape, &params);
    let mut v = v0.clone();
    for _ in 0..steps {
        v = scene.step(&tape, &v, &p)?.0;
    }
    let loss = v.ux.dot(v.ux)?.add(v.uy.dot(v.uy)?)?.mul_scalar(0.5)?;
    let taped = t.elapsed().as_secs_f64();
    let t = Instant::now();
    tape.backward(loss, &[v0.ux, v0.uy])?;
    let backward = t.elapsed().as_secs_f64();
    let ms = |s: f64| s / steps as f64 * 1e3;
    Ok(json!({
        "steps": steps,
        "forward_ms_per_step": ms(plain),
        "taped_forward_ms_per_step": ms(taped),
        "backward_ms_per_step": ms(backward),
        "forward_backward_ms_per_step": ms(taped + backward),
        "backward_over_forward": backward / taped,
        "forward_backward_over_plain_forward": (taped + backward) / plain,
        "tape_peak_bytes_per_step": tape.stats().peak_bytes / steps,
    }))
}

/// A heat map of `field` (`[nx, ny]`, axis 0 along x) over `[0, size[0]] ×
/// [0, size[1]]`, averaged into at most `max_cols` columns so the SVG stays
/// small, on a blue–white–red scale symmetric about zero clipped at `clip`;
/// `solid` cells (same shape, or `None`) in grey.
pub fn write_heatmap(
    path: &std::path::Path,
    title: &str,
    field: &Array2<f64>,
    solid: Option<&Array2<bool>>,
    size: [f64; 2],
    clip: f64,
    max_cols: usize,
) -> Result<()> {
    use plotters::prelude::*;
    let (nx, ny) = field.dim();
    let block = nx.div_ceil(max_cols).max(1);
    let (bx, by) = (nx.div_ceil(block), ny.div_ceil(block));
    let width = 1000u32;
    let height = ((width as f64 - 40.0) * size[1] / size[0]) as u32 + 70;
    let root = SVGBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 15))
        .margin(8)
        .build_cartesian_2d(0.0..size[0], 0.0..size[1])?;
    let (hx, hy) = (size[0] / nx as f64, size[1] / ny as f64);
    let mut rects = Vec::with_capacity(bx * by);
    for a in 0..bx {
        for b in 0..by {
            let (i0, i1) = (a * block, ((a + 1) * block).min(nx));
            let (j0, j1) = (b * block, ((b + 1) * block).min(ny));
            let (mut sum, mut count, mut solid_count) = (0.0, 0usize, 0usize);
            for i in i0..i1 {
                for j in j0..j1 {
                    if solid.is_some_and(|m| m[[i, j]]) {
                        solid_count += 1;
                    } else {
                        sum += field[[i, j]];
                        count += 1;
                    }
                }
            }
            let colour = if solid_count * 2 > (i1 - i0) * (j1 - j0) {
                RGBColor(150, 150, 150)
            } else {
                let t = (sum / count.max(1) as f64 / clip).clamp(-1.0, 1.0);
                let fade = |t: f64| (255.0 * (1.0 - t.abs())) as u8;
                if t >= 0.0 {
                    RGBColor(255, fade(t), fade(t))
                } else {
                    RGBColor(fade(t), fade(t), 255)
                }
            };
            rects.push(Rectangle::new(
                [
                    (i0 as f64 * hx, j0 as f64 * hy),
                    (i1 as f64 * hx, j1 as f64 * hy),
                ],
                colour.filled(),
            ));
        }
    }
    chart.draw_series(rects)?;
    root.present()?;
    Ok(())
}

/// The peak resident set size of this process in bytes (`VmHWM` in
/// `/proc/self/status`), or `None` where that file does not exist.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// The floors of a run for its JSON line: each check as text and whether all
/// are met (`null` where none applies).
pub fn floors_json(floors: &[FloorCheck]) -> Value {
    if floors.is_empty() {
        return Value::Null;
    }
    json!({
        "checks": floors.iter().map(|f| f.to_string()).collect::<Vec<_>>(),
        "met": all_met(floors),
    })
}

/// An error naming `run` when a floor is missed: what a validation example
/// returns after printing its JSON line, so its exit status follows the floors.
pub fn require_floors(run: &str, floors: &[FloorCheck]) -> Result<()> {
    if all_met(floors) {
        Ok(())
    } else {
        Err(format!("{run}: a published floor is not met").into())
    }
}
