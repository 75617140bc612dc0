//! The lid-driven cavity, run to steady state and compared with the table of
//! Ghia, Ghia and Shin (J. Comput. Phys. 48, 1982) shipped in
//! `data/ghia1982_cavity.json`.
//!
//! The unit square, no-slip walls, the lid (y = 1) moving along +x at speed 1,
//! ν = 1/Re; MacCormack advection with the limiter, Courant number 0.5 at the
//! lid speed, explicit viscosity where it is stable at that time step and
//! implicit otherwise, the scene's default pressure solver. The run stops when
//! the velocity changes by less than `--tol` per unit time (the largest change
//! of any face over the last 100 steps, divided by their duration), or at
//! `--max-time`.
//!
//! Reported (the last stdout line, JSON): `centerline_u` (`y`, `u` along
//! x = 0.5) and `centerline_v` (`x`, `v` along y = 0.5) on the grid, normalised
//! by the lid speed; at Ghia's 17 points of each line the values interpolated
//! linearly from the grid, the table's, and the largest deviation; steps, time,
//! per-step time, `peak_rss_bytes`. A chart of both profiles against the table
//! is written to `OUT/cavity_re{Re}_n{n}.svg`.
//!
//! Floor (the flow-step issue): at 128 x 128 and Re = 100, |u − u_Ghia| ≤ 0.02
//! at every tabulated point.
//!
//! `cargo run --release --example cavity -- [--re 100|400|1000] [--n 128]
//! [--tol 1e-4] [--max-time T] [--small] [--out DIR]`

mod common;
mod flow_common;

use std::path::PathBuf;
use std::time::Instant;

use diffphys::flow::{Advection, FlowState, Scene, Sides, ViscosityMode};
use ndarray::Array2;
use serde_json::{json, Value};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

const LID: f64 = 1.0;
/// The floor's tolerance on u at Re = 100, 128 x 128.
const FLOOR: f64 = 0.02;

/// Ghia's table for one Reynolds number.
struct Ghia {
    y: Vec<f64>,
    u: Vec<f64>,
    x: Vec<f64>,
    v: Vec<f64>,
}

fn ghia(re: u32) -> Result<Ghia> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/ghia1982_cavity.json");
    let text = std::fs::read_to_string(&path).map_err(|e| {
        format!(
            "the cavity example needs {} (in the repository): {e}",
            path.display()
        )
    })?;
    let table: Value = serde_json::from_str(&text)?;
    let key = format!("re{re}");
    let numbers = |v: &Value| -> Result<Vec<f64>> {
        v.as_array()
            .ok_or_else(|| {
                format!(
                    "{}: no table for Re = {re} (100, 400, 1000)",
                    path.display()
                )
            })?
            .iter()
            .map(|x| x.as_f64().ok_or_else(|| "not a number".into()))
            .collect()
    };
    let (u, v) = (
        &table["u_along_vertical_centreline"],
        &table["v_along_horizontal_centreline"],
    );
    Ok(Ghia {
        y: numbers(&u["y"])?,
        u: numbers(&u[&key])?,
        x: numbers(&v["x"])?,
        v: numbers(&v[&key])?,
    })
}

/// Linear interpolation of the samples `(s, f)` (ascending `s`) at `q`.
fn interpolate(s: &[f64], f: &[f64], q: f64) -> f64 {
    let k = s.partition_point(|&p| p <= q).clamp(1, s.len() - 1);
    let t = (q - s[k - 1]) / (s[k] - s[k - 1]);
    f[k - 1] + t * (f[k] - f[k - 1])
}

/// `u` along x = 0.5 (y ascending, walls included) and `v` along y = 0.5 (x
/// ascending, walls included), each as (coordinates, values / lid speed).
#[allow(clippy::type_complexity)]
fn centrelines(scene: &Scene, s: &FlowState<f64>) -> ((Vec<f64>, Vec<f64>), (Vec<f64>, Vec<f64>)) {
    let g = scene.grid();
    let (nx, ny, dx, dy) = (g.nx, g.ny, g.dx, g.dy);
    // u_x[a, b] at (a dx, (b + ½) dy): interpolate in x between the faces around 0.5
    let xa = 0.5 / dx;
    let (a0, ta) = ((xa.floor() as usize).min(nx - 1), xa - xa.floor());
    let mut y = vec![0.0];
    let mut u = vec![0.0];
    for b in 0..ny {
        y.push((b as f64 + 0.5) * dy);
        u.push(((1.0 - ta) * s.ux[[a0, b]] + ta * s.ux[[a0 + 1, b]]) / LID);
    }
    y.push(1.0);
    u.push(1.0);
    // u_y[a, b] at ((a + ½) dx, b dy)
    let yb = 0.5 / dy;
    let (b0, tb) = ((yb.floor() as usize).min(ny - 1), yb - yb.floor());
    let mut x = vec![0.0];
    let mut v = vec![0.0];
    for a in 0..nx {
        x.push((a as f64 + 0.5) * dx);
        v.push(((1.0 - tb) * s.uy[[a, b0]] + tb * s.uy[[a, b0 + 1]]) / LID);
    }
    x.push(1.0);
    v.push(0.0);
    ((y, u), (x, v))
}

/// The largest change of any face between two states.
fn max_change(a: &FlowState<f64>, b: &FlowState<f64>) -> f64 {
    let d = |p: &Array2<f64>, q: &Array2<f64>| {
        p.iter()
            .zip(q)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
    };
    d(&a.ux, &b.ux).max(d(&a.uy, &b.uy))
}

struct Options {
    re: u32,
    n: usize,
    tol: f64,
    max_time: Option<f64>,
}

fn parse() -> Result<(common::ExampleArgs, Options)> {
    let mut rest = Vec::new();
    let (mut re, mut n, mut tol, mut max_time) = (100, None, 1e-4, None);
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        match a.as_str() {
            "--re" => re = value("--re")?.parse()?,
            "--n" => n = Some(value("--n")?.parse()?),
            "--tol" => tol = value("--tol")?.parse()?,
            "--max-time" => max_time = Some(value("--max-time")?.parse()?),
            _ => rest.push(a),
        }
    }
    let args = common::ExampleArgs::parse_from("cavity", rest.into_iter())?;
    let n = n.unwrap_or(args.pick(128, 32));
    if n < 8 || n % 2 != 0 {
        return Err(format!("--n must be even and at least 8, got {n}").into());
    }
    Ok((
        args,
        Options {
            re,
            n,
            tol,
            max_time,
        },
    ))
}

fn main() -> Result<()> {
    let (args, opt) = parse()?;
    let table = ghia(opt.re)?;
    let nu = LID / opt.re as f64;
    let h = 1.0 / opt.n as f64;
    let dt = 0.5 * h / LID;
    let base = Scene::builder(opt.n, opt.n, [1.0, 1.0])
        .sides(Sides::cavity(LID))
        .viscosity(nu)
        .dt(dt)
        .advection(Advection::MacCormack { limiter: true });
    // the explicit diffusion number ν dt (1/dx² + 1/dy²); stable to ½
    let explicit = nu * dt * 2.0 / (h * h) <= 0.45;
    let mode = if explicit {
        ViscosityMode::Explicit
    } else {
        ViscosityMode::Implicit
    };
    let scene = base.viscosity_mode(mode).build()?;
    // Ghia's flows take this long to settle from rest (lid time units, generous).
    let max_time = opt.max_time.unwrap_or(match opt.re {
        0..=150 => 40.0,
        151..=500 => 80.0,
        _ => 160.0,
    });
    println!(
        "lid-driven cavity, Re = {}, {} x {} cells, dt = {dt:.3e}, {mode:?} viscosity, {:?} pressure; \
         to d|u|/dt < {:.0e} or t = {max_time}",
        opt.re,
        opt.n,
        opt.n,
        scene.settings().pressure_solver,
        opt.tol
    );

    const WINDOW: usize = 100;
    let params = scene.params();
    let mut state = FlowState::<f64>::zeros(&scene);
    let mut mark = state.clone();
    let t0 = Instant::now();
    let (mut steps, mut rate, mut pressure_iterations) = (0usize, f64::INFINITY, 0usize);
    while (steps as f64) * dt < max_time {
        let (next, info) = scene.forward(&state, &params)?;
        pressure_iterations += info.pressure_iterations.iter().sum::<usize>();
        state = next;
        steps += 1;
        if steps % WINDOW == 0 {
            rate = max_change(&state, &mark) / (WINDOW as f64 * dt);
            mark = state.clone();
            if steps % (20 * WINDOW) == 0 {
                println!(
                    "  t = {:7.2}  steps {steps:6}  d|u|/dt = {rate:.2e}",
                    steps as f64 * dt
                );
            }
            if rate < opt.tol {
                break;
            }
        }
    }
    let seconds = t0.elapsed().as_secs_f64();
    let steady = rate < opt.tol;

    let ((y, u), (x, v)) = centrelines(&scene, &state);
    let u_at: Vec<f64> = table.y.iter().map(|&q| interpolate(&y, &u, q)).collect();
    let v_at: Vec<f64> = table.x.iter().map(|&q| interpolate(&x, &v, q)).collect();
    let dev = |ours: &[f64], theirs: &[f64]| -> Vec<f64> {
        ours.iter()
            .zip(theirs)
            .map(|(a, b)| (a - b).abs())
            .collect()
    };
    let (du, dv) = (dev(&u_at, &table.u), dev(&v_at, &table.v));
    let worst = |d: &[f64]| d.iter().cloned().fold(0.0f64, f64::max);
    let (max_du, max_dv) = (worst(&du), worst(&dv));
    let at_floor = opt.re == 100 && opt.n == 128;
    let floor_met = max_du <= FLOOR;

    println!("   y       u (ours)   u (Ghia)   |diff|      x       v (ours)   v (Ghia)   |diff|");
    for k in 0..table.y.len() {
        println!(
            "  {:.4}  {:+.5}  {:+.5}  {:.5}     {:.4}  {:+.5}  {:+.5}  {:.5}",
            table.y[k], u_at[k], table.u[k], du[k], table.x[k], v_at[k], table.v[k], dv[k]
        );
    }
    println!(
        "Re = {}: max |u - u_Ghia| = {max_du:.4}, max |v - v_Ghia| = {max_dv:.4}; {steps} steps to t = {:.2} \
         ({}), {seconds:.1} s ({:.3} ms per step)",
        opt.re,
        steps as f64 * dt,
        if steady { "steady" } else { "NOT steady: the time limit came first" },
        seconds / steps as f64 * 1e3
    );
    if at_floor {
        println!(
            "floor (128 x 128, Re = 100: |u - u_Ghia| <= {FLOOR} at every point): {}",
            if floor_met { "met" } else { "NOT met" }
        );
    }
    let chart = args.out.join(format!("cavity_re{}_n{}.svg", opt.re, opt.n));
    write_chart(&chart, opt.re, opt.n, (&y, &u), (&x, &v), &table)?;
    println!("wrote {}", chart.display());

    common::print_json_line(&json!({
        "re": opt.re, "n": opt.n, "dt": dt, "viscosity_mode": format!("{mode:?}"),
        "pressure_solver": format!("{:?}", scene.settings().pressure_solver),
        "advection": format!("{:?}", scene.settings().advection),
        "centerline_u": {"y": y, "u": u},
        "centerline_v": {"x": x, "v": v},
        "ghia": {
            "y": table.y, "u_ours": u_at, "u_ghia": table.u,
            "x": table.x, "v_ours": v_at, "v_ghia": table.v,
        },
        "max_abs_u_deviation": max_du, "max_abs_v_deviation": max_dv,
        "floor": if at_floor { json!({"max_abs_u_deviation": FLOOR, "met": floor_met}) } else { Value::Null },
        "steady": steady, "rate_at_end": rate, "tol": opt.tol,
        "steps": steps, "time": steps as f64 * dt, "wall_s": seconds,
        "ms_per_step": seconds / steps as f64 * 1e3,
        "pressure_iterations_per_step": pressure_iterations as f64 / steps as f64,
        "peak_rss_bytes": flow_common::peak_rss_bytes(),
    }));
    Ok(())
}

fn write_chart(
    path: &std::path::Path,
    re: u32,
    n: usize,
    (y, u): (&[f64], &[f64]),
    (x, v): (&[f64], &[f64]),
    table: &Ghia,
) -> Result<()> {
    use plotters::prelude::*;
    let root = SVGBackend::new(path, (900, 440)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(450);
    let mut c = ChartBuilder::on(&left)
        .caption(
            format!("u along x = 0.5, Re = {re}, {n}x{n}"),
            ("sans-serif", 16),
        )
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(45)
        .build_cartesian_2d(-0.6..1.05, 0.0..1.0)?;
    c.configure_mesh().x_desc("u / U").y_desc("y").draw()?;
    c.draw_series(LineSeries::new(
        u.iter().zip(y).map(|(&a, &b)| (a, b)),
        &BLUE,
    ))?
    .label("diffphys-flow")
    .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLUE));
    c.draw_series(
        table
            .u
            .iter()
            .zip(&table.y)
            .map(|(&a, &b)| Circle::new((a, b), 4, RED.stroke_width(2))),
    )?
    .label("Ghia et al. 1982")
    .legend(|(x, y)| Circle::new((x + 8, y), 4, RED.stroke_width(2)));
    c.configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE)
        .draw()?;
    let mut c = ChartBuilder::on(&right)
        .caption(
            format!("v along y = 0.5, Re = {re}, {n}x{n}"),
            ("sans-serif", 16),
        )
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(45)
        .build_cartesian_2d(0.0..1.0, -0.6..0.45)?;
    c.configure_mesh().x_desc("x").y_desc("v / U").draw()?;
    c.draw_series(LineSeries::new(
        x.iter().zip(v).map(|(&a, &b)| (a, b)),
        &BLUE,
    ))?;
    c.draw_series(
        table
            .x
            .iter()
            .zip(&table.v)
            .map(|(&a, &b)| Circle::new((a, b), 4, RED.stroke_width(2))),
    )?;
    root.present()?;
    Ok(())
}
