//! Flow around a cylinder in a channel: the DFG benchmark of Schaefer and
//! Turek (1996), test cases 2D-1 (Re = 20, steady) and 2D-2 (Re = 100,
//! periodic), beside the published reference intervals shipped in
//! `data/schaefer_turek1996_cylinder.json`.
//!
//! The channel is 2.2 × 0.41, the cylinder of diameter D = 0.1 is centred at
//! (0.2, 0.2), ν = 1e-3, density 1; parabolic inflow of peak Um (0.3 for
//! 2D-1, 1.5 for 2D-2) on the left, outflow on the right, no-slip walls and
//! cylinder. The grid has `cpd` cells across the diameter (square cells of
//! h = D / cpd, 22 cpd x 4.1 cpd cells) and the cylinder is a staircase of
//! solid cells. MacCormack advection with the limiter, Courant number 0.4 at
//! Um, explicit viscosity where stable, implicit otherwise.
//!
//! - 2D-1: from the inflow profile extended through the channel, run until the
//!   velocity changes by less than `--tol` (1e-4) per unit time; drag and lift
//!   coefficients `cD = 2 F_x / (Ubar² D)`, `cL = 2 F_y / (Ubar² D)` (the
//!   force of the flow on the staircase body, pressure and wall shear), and the
//!   pressure difference `dp = p(0.15, 0.2) − p(0.25, 0.2)` (the pressure of
//!   the fluid cells next to the front and back points, extrapolated to them).
//! - 2D-2: from the same start, run to `t_end`; over the last `window` time
//!   units, `max cD`, `max cL` and the Strouhal number `St = D f / Ubar` from
//!   the period of the lift (its up-crossings of the mean).
//!
//! Each case runs at each grid of `--cpd` (a refinement table with the error
//! against the reference interval); the finest is the stated grid of the
//! floors: 2D-1 drag within 5 % of the interval, 2D-2 Strouhal within 5 %.
//! A vorticity chart of the 2D-2 wake at its last step is written to
//! `OUT/cylinder_2d2_vorticity.svg`, the lift history to
//! `OUT/cylinder_2d2_lift.svg`. The last stdout line is the JSON of it all.
//!
//! `cargo run --release --example cylinder -- [--cpd 10,20] [--cases 2d1,2d2]
//! [--t-end 12] [--window 4] [--tol 1e-4] [--max-time 40] [--small] [--out DIR]`

mod common;
mod flow_common;

use std::path::PathBuf;
use std::time::Instant;

use diffphys::flow::diagnostics::{obstacle_force, vorticity};
use diffphys::flow::{Advection, FlowState, Obstacle, Scene, Sides, ViscosityMode};
use ndarray::Array2;
use serde_json::{json, Value};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

const LENGTH: f64 = 2.2;
const HEIGHT: f64 = 0.41;
const CENTRE: [f64; 2] = [0.2, 0.2];
const D: f64 = 0.1;
const NU: f64 = 1e-3;

/// The reference intervals of one case, by name.
fn intervals(case: &str) -> Result<serde_json::Map<String, Value>> {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/schaefer_turek1996_cylinder.json");
    let text = std::fs::read_to_string(&path).map_err(|e| {
        format!(
            "the cylinder example needs {} (in the repository): {e}",
            path.display()
        )
    })?;
    let table: Value = serde_json::from_str(&text)?;
    Ok(table["cases"][case]["intervals"]
        .as_object()
        .ok_or_else(|| format!("{}: no case {case}", path.display()))?
        .clone())
}

fn interval(map: &serde_json::Map<String, Value>, key: &str) -> [f64; 2] {
    let v = &map[key];
    [
        v[0].as_f64().unwrap_or(f64::NAN),
        v[1].as_f64().unwrap_or(f64::NAN),
    ]
}

/// How far `x` lies outside `[lo, hi]`, relative to the nearer bound (0 inside).
fn outside(x: f64, [lo, hi]: [f64; 2]) -> f64 {
    if x < lo {
        (lo - x) / lo.abs()
    } else if x > hi {
        (x - hi) / hi.abs()
    } else {
        0.0
    }
}

/// The channel at `cpd` cells per diameter with parabolic inflow of peak `um`.
fn scene(cpd: usize, um: f64) -> Result<Scene> {
    let h = D / cpd as f64;
    let (nx, ny) = ((LENGTH / h).round() as usize, (HEIGHT / h).round() as usize);
    let dt = 0.4 * h / um;
    let explicit =
        NU * dt * (1.0 / (LENGTH / nx as f64).powi(2) + 1.0 / (HEIGHT / ny as f64).powi(2)) <= 0.45;
    Ok(Scene::builder(nx, ny, [LENGTH, HEIGHT])
        .sides(Sides::channel())
        .obstacle(Obstacle::cylinder(CENTRE, D / 2.0))
        .parabolic_inflow(um)
        .viscosity(NU)
        .dt(dt)
        .advection(Advection::MacCormack { limiter: true })
        .viscosity_mode(if explicit {
            ViscosityMode::Explicit
        } else {
            ViscosityMode::Implicit
        })
        .substepping(true)
        .build()?)
}

/// The inflow profile carried through the whole channel (the obstacle's faces
/// are set to zero by the first step).
fn start(scene: &Scene) -> FlowState<f64> {
    let profile = scene.params::<f64>().inflow;
    let g = scene.grid();
    let ux = Array2::from_shape_fn(g.shape_x(), |(_, b)| profile[b]);
    FlowState::from_velocity(scene, ux, Array2::zeros(g.shape_y()))
}

/// `(cD, cL)` of a state.
fn coefficients(scene: &Scene, s: &FlowState<f64>, ubar: f64) -> Result<(f64, f64)> {
    let f = obstacle_force(
        scene.force_weights(),
        s.ux.view(),
        s.uy.view(),
        s.pressure.view(),
        NU,
    )?;
    let c = 2.0 / (ubar * ubar * D);
    Ok((c * f[0], c * f[1]))
}

/// `p(0.15, 0.2) − p(0.25, 0.2)`: along the two rows of cells around y = 0.2,
/// the last fluid cells before the body (and the first after it) extrapolated
/// linearly to the front (back) point, then averaged over the two rows.
fn pressure_difference(scene: &Scene, s: &FlowState<f64>) -> f64 {
    let g = scene.grid();
    let solid = scene.solid();
    let yc = CENTRE[1] / g.dy - 0.5;
    let rows = [yc.floor() as usize, yc.ceil() as usize];
    let weight = [1.0 - (yc - yc.floor()), yc - yc.floor()];
    let xc = |i: usize| (i as f64 + 0.5) * g.dx;
    let (front, back) = (CENTRE[0] - D / 2.0, CENTRE[0] + D / 2.0);
    let mut dp = 0.0;
    for (&j, &w) in rows.iter().zip(&weight) {
        let w = if rows[0] == rows[1] { 0.5 } else { w };
        let first_solid = (0..g.nx).find(|&i| solid[[i, j]]).unwrap_or(g.nx - 1);
        let last_solid = (0..g.nx).rev().find(|&i| solid[[i, j]]).unwrap_or(0);
        let (f1, f0) = (first_solid - 1, first_solid - 2);
        let p_front = s.pressure[[f1, j]]
            + (front - xc(f1)) * (s.pressure[[f1, j]] - s.pressure[[f0, j]]) / g.dx;
        let (b1, b0) = (last_solid + 1, last_solid + 2);
        let p_back = s.pressure[[b1, j]]
            + (back - xc(b1)) * (s.pressure[[b1, j]] - s.pressure[[b0, j]]) / g.dx;
        dp += w * (p_front - p_back);
    }
    dp
}

fn largest_change(a: &FlowState<f64>, b: &FlowState<f64>) -> f64 {
    let d = |p: &Array2<f64>, q: &Array2<f64>| {
        p.iter()
            .zip(q)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
    };
    d(&a.ux, &b.ux).max(d(&a.uy, &b.uy))
}

fn grid_json(scene: &Scene, cpd: usize) -> Value {
    let g = scene.grid();
    let solid = scene.solid();
    // cells across the diameter: the widest run of solid cells in a row
    let across = (0..g.ny)
        .map(|j| (0..g.nx).filter(|&i| solid[[i, j]]).count())
        .max()
        .unwrap_or(0);
    json!({
        "cells_per_diameter": cpd, "nx": g.nx, "ny": g.ny, "h": g.dx,
        "obstacle_cells_across_diameter": across, "solid_cells": solid.iter().filter(|&&s| s).count(),
        "dt": scene.dt(), "viscosity_mode": format!("{:?}", scene.settings().viscosity_mode),
        "pressure_solver": format!("{:?}", scene.settings().pressure_solver),
    })
}

/// 2D-1 at `cpd`: run to steady state, report cD, cL, dp.
fn steady(cpd: usize, max_time: f64, tol: f64) -> Result<(Value, Scene, FlowState<f64>)> {
    let (um, ubar) = (0.3, 0.2);
    let scene = scene(cpd, um)?;
    let params = scene.params();
    let mut s = start(&scene);
    let mut mark = s.clone();
    const WINDOW: usize = 100;
    let dt = scene.dt();
    let t0 = Instant::now();
    let (mut steps, mut rate, mut substeps) = (0usize, f64::INFINITY, 0usize);
    while (steps as f64) * dt < max_time {
        let (next, info) = scene.forward(&s, &params)?;
        substeps += info.substeps;
        s = next;
        steps += 1;
        if steps % WINDOW == 0 {
            rate = largest_change(&s, &mark) / (WINDOW as f64 * dt);
            mark = s.clone();
            if rate < tol {
                break;
            }
        }
    }
    let seconds = t0.elapsed().as_secs_f64();
    let (cd, cl) = coefficients(&scene, &s, ubar)?;
    let dp = pressure_difference(&scene, &s);
    println!(
        "  2D-1 cpd {cpd:3}: cD {cd:.4}  cL {cl:+.5}  dp {dp:.4}  ({steps} steps to t = {:.2}, {}; {seconds:.1} s, {:.2} ms/step)",
        steps as f64 * dt,
        if rate < tol { "steady" } else { "NOT steady" },
        seconds / steps as f64 * 1e3
    );
    let row = json!({
        "grid": grid_json(&scene, cpd), "cd": cd, "cl": cl, "dp": dp,
        "steady": rate < tol, "tol": tol, "rate_at_end": rate, "steps": steps, "substeps": substeps,
        "time": steps as f64 * dt, "wall_s": seconds, "ms_per_step": seconds / steps as f64 * 1e3,
    });
    Ok((row, scene, s))
}

/// A 2D-2 run: its JSON row, the scene, the last state, the `(t, cD, cL)` history.
type PeriodicRun = (Value, Scene, FlowState<f64>, Vec<[f64; 3]>);

/// 2D-2 at `cpd`: run to `t_end`, analyse the last `window`.
fn periodic(cpd: usize, t_end: f64, window: f64) -> Result<PeriodicRun> {
    let (um, ubar) = (1.5, 1.0);
    let scene = scene(cpd, um)?;
    let params = scene.params();
    let dt = scene.dt();
    let mut s = start(&scene);
    let t0 = Instant::now();
    let steps = (t_end / dt).round() as usize;
    let record_from = ((t_end - window) / dt).round() as usize;
    let mut history = Vec::new(); // (t, cD, cL)
    let mut substeps = 0usize;
    for k in 1..=steps {
        let (next, info) = scene.forward(&s, &params)?;
        substeps += info.substeps;
        s = next;
        if k >= record_from {
            let (cd, cl) = coefficients(&scene, &s, ubar)?;
            history.push([k as f64 * dt, cd, cl]);
        }
    }
    let seconds = t0.elapsed().as_secs_f64();
    let cd_max = history
        .iter()
        .map(|h| h[1])
        .fold(f64::NEG_INFINITY, f64::max);
    let cl_max = history
        .iter()
        .map(|h| h[2])
        .fold(f64::NEG_INFINITY, f64::max);
    let cl_min = history.iter().map(|h| h[2]).fold(f64::INFINITY, f64::min);
    let mean = history.iter().map(|h| h[2]).sum::<f64>() / history.len().max(1) as f64;
    // up-crossings of the mean lift, interpolated linearly
    let crossings: Vec<f64> = history
        .windows(2)
        .filter(|w| w[0][2] < mean && w[1][2] >= mean)
        .map(|w| w[0][0] + (mean - w[0][2]) / (w[1][2] - w[0][2]) * (w[1][0] - w[0][0]))
        .collect();
    let (strouhal, periods) = if crossings.len() >= 3 {
        let p = (crossings[crossings.len() - 1] - crossings[0]) / (crossings.len() - 1) as f64;
        (
            D / (p * ubar),
            crossings
                .windows(2)
                .map(|w| w[1] - w[0])
                .collect::<Vec<_>>(),
        )
    } else {
        (f64::NAN, Vec::new())
    };
    // periodic: the last two periods' lengths agree to 1 %
    let settled = periods.len() >= 2 && {
        let (a, b) = (periods[periods.len() - 1], periods[periods.len() - 2]);
        (a - b).abs() / a < 0.01
    };
    println!(
        "  2D-2 cpd {cpd:3}: St {strouhal:.4}  max cD {cd_max:.4}  max cL {cl_max:.4}  ({} lift periods in the last {window} time units, {}; {steps} steps, {seconds:.1} s, {:.2} ms/step)",
        periods.len(),
        if settled { "periodic" } else { "NOT yet periodic" },
        seconds / steps as f64 * 1e3
    );
    let row = json!({
        "grid": grid_json(&scene, cpd), "strouhal": strouhal, "cd_max": cd_max, "cl_max": cl_max,
        "cl_min": cl_min, "cl_mean": mean, "periods": periods, "periodic": settled,
        "steps": steps, "substeps": substeps, "t_end": t_end, "window": window,
        "wall_s": seconds, "ms_per_step": seconds / steps as f64 * 1e3,
    });
    Ok((row, scene, s, history))
}

/// Observed orders of convergence of `errors` on grids of `cpd` cells per diameter.
fn orders(cpd: &[usize], errors: &[f64]) -> Vec<Option<f64>> {
    (1..errors.len())
        .map(|k| {
            let (e0, e1) = (errors[k - 1], errors[k]);
            (e0 > 0.0 && e1 > 0.0)
                .then(|| (e0 / e1).ln() / (cpd[k] as f64 / cpd[k - 1] as f64).ln())
        })
        .collect()
}

struct Options {
    cpd: Vec<usize>,
    cases: Vec<String>,
    t_end: f64,
    window: f64,
    max_time: f64,
    tol: f64,
}

fn parse() -> Result<(common::ExampleArgs, Options)> {
    let mut rest = Vec::new();
    let (mut cpd, mut cases, mut t_end, mut window, mut max_time) = (None, None, None, None, None);
    let mut tol = 1e-4;
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        match a.as_str() {
            "--cpd" => {
                cpd = Some(
                    value("--cpd")?
                        .split(',')
                        .map(|s| s.parse::<usize>())
                        .collect::<std::result::Result<Vec<_>, _>>()?,
                )
            }
            "--cases" => {
                cases = Some(
                    value("--cases")?
                        .split(',')
                        .map(str::to_lowercase)
                        .collect::<Vec<_>>(),
                )
            }
            "--t-end" => t_end = Some(value("--t-end")?.parse()?),
            "--window" => window = Some(value("--window")?.parse()?),
            "--max-time" => max_time = Some(value("--max-time")?.parse()?),
            "--tol" => tol = value("--tol")?.parse()?,
            _ => rest.push(a),
        }
    }
    let args = common::ExampleArgs::parse_from("cylinder", rest.into_iter())?;
    let cpd = cpd.unwrap_or_else(|| args.pick(vec![10, 20], vec![8]));
    if cpd.iter().any(|&c| c < 4) {
        return Err("--cpd: at least 4 cells across the diameter".into());
    }
    let cases = cases.unwrap_or_else(|| vec!["2d1".into(), "2d2".into()]);
    if let Some(c) = cases.iter().find(|c| !matches!(c.as_str(), "2d1" | "2d2")) {
        return Err(format!("--cases: 2d1 and/or 2d2, not {c:?}").into());
    }
    let t_end = t_end.unwrap_or(args.pick(12.0, 3.0));
    let window = window.unwrap_or(args.pick(4.0, 1.5));
    if !(window > 0.0 && window < t_end) {
        return Err(format!("--window must lie in (0, t_end = {t_end})").into());
    }
    let max_time = max_time.unwrap_or(args.pick(40.0, 8.0));
    Ok((
        args,
        Options {
            cpd,
            cases,
            t_end,
            window,
            max_time,
            tol,
        },
    ))
}

fn main() -> Result<()> {
    let (args, opt) = parse()?;
    let mut out = serde_json::Map::new();
    out.insert("cells_per_diameter".into(), json!(opt.cpd));
    let stated = *opt.cpd.iter().max().expect("at least one grid");

    if opt.cases.iter().any(|c| c == "2d1") {
        let iv = intervals("2D-1")?;
        let (cd_iv, cl_iv, dp_iv) = (
            interval(&iv, "cd"),
            interval(&iv, "cl"),
            interval(&iv, "dp"),
        );
        println!("2D-1 (Re = 20, steady): reference cD {cd_iv:?}, cL {cl_iv:?}, dp {dp_iv:?}");
        let mut rows = Vec::new();
        let mut last = None;
        for &c in &opt.cpd {
            let (row, scene, s) = steady(c, opt.max_time, opt.tol)?;
            rows.push(row);
            last = Some((scene, s));
        }
        let err = |k: &str, iv: [f64; 2]| -> Vec<f64> {
            rows.iter()
                .map(|r| outside(r[k].as_f64().unwrap_or(f64::NAN), iv))
                .collect()
        };
        let (ecd, ecl, edp) = (err("cd", cd_iv), err("cl", cl_iv), err("dp", dp_iv));
        println!(
            "  cpd | cD error | cL error | dp error   (relative distance outside the interval)"
        );
        for (k, c) in opt.cpd.iter().enumerate() {
            println!(
                "  {c:3} | {:7.2} % | {:7.2} % | {:7.2} %",
                ecd[k] * 1e2,
                ecl[k] * 1e2,
                edp[k] * 1e2
            );
        }
        let at = opt
            .cpd
            .iter()
            .position(|&c| c == stated)
            .expect("the stated grid ran");
        let floor_met = ecd[at] <= 0.05;
        println!(
            "  floor (2D-1 drag within 5 % of the interval at cpd {stated}): {} ({:.2} %)",
            if floor_met { "met" } else { "NOT met" },
            ecd[at] * 1e2
        );
        let (scene, s) = last.expect("one grid at least");
        let costs = flow_common::step_costs(&scene, &s, args.pick(10, 3))?;
        out.insert(
            "2d1".into(),
            json!({
                "reference": iv, "runs": rows,
                "error_outside_interval": {"cd": ecd, "cl": ecl, "dp": edp},
                "observed_order": {"cd": orders(&opt.cpd, &ecd), "cl": orders(&opt.cpd, &ecl), "dp": orders(&opt.cpd, &edp)},
                "stated_cells_per_diameter": stated,
                "floor": {"cd_within": 0.05, "met": floor_met},
                "step_costs_at_stated_grid": costs,
            }),
        );
    }

    if opt.cases.iter().any(|c| c == "2d2") {
        let iv = intervals("2D-2")?;
        let (st_iv, cd_iv, cl_iv) = (
            interval(&iv, "strouhal"),
            interval(&iv, "cd_max"),
            interval(&iv, "cl_max"),
        );
        println!(
            "2D-2 (Re = 100, periodic): reference St {st_iv:?}, max cD {cd_iv:?}, max cL {cl_iv:?}; t_end {}, window {}",
            opt.t_end, opt.window
        );
        let mut rows = Vec::new();
        let mut last = None;
        for &c in &opt.cpd {
            let (row, scene, s, history) = periodic(c, opt.t_end, opt.window)?;
            rows.push(row);
            last = Some((scene, s, history));
        }
        let err = |k: &str, iv: [f64; 2]| -> Vec<f64> {
            rows.iter()
                .map(|r| outside(r[k].as_f64().unwrap_or(f64::NAN), iv))
                .collect()
        };
        let (est, ecd, ecl) = (
            err("strouhal", st_iv),
            err("cd_max", cd_iv),
            err("cl_max", cl_iv),
        );
        println!("  cpd | St error | max cD error | max cL error   (relative distance outside the interval)");
        for (k, c) in opt.cpd.iter().enumerate() {
            println!(
                "  {c:3} | {:7.2} % | {:10.2} % | {:10.2} %",
                est[k] * 1e2,
                ecd[k] * 1e2,
                ecl[k] * 1e2
            );
        }
        let at = opt
            .cpd
            .iter()
            .position(|&c| c == stated)
            .expect("the stated grid ran");
        let floor_met = est[at] <= 0.05;
        println!(
            "  floor (2D-2 Strouhal within 5 % at cpd {stated}): {} ({:.2} %)",
            if floor_met { "met" } else { "NOT met" },
            est[at] * 1e2
        );
        let (scene, s, history) = last.expect("one grid at least");
        let omega = vorticity(&scene, s.ux.view(), s.uy.view())?;
        let solid = scene.solid();
        let (wx, wy) = omega.dim();
        // node (a, b) of the vorticity lies between cells a..a+1 and b..b+1
        let mask = Array2::from_shape_fn((wx, wy), |(a, b)| {
            (a..(a + 2).min(solid.dim().0))
                .any(|i| (b..(b + 2).min(solid.dim().1)).any(|j| solid[[i, j]]))
        });
        let path = args.out.join("cylinder_2d2_vorticity.svg");
        flow_common::write_heatmap(
            &path,
            &format!(
                "2D-2 vorticity at t = {:.2} ({}x{} cells; clipped at ±40 /s)",
                opt.t_end,
                scene.grid().nx,
                scene.grid().ny
            ),
            &omega,
            Some(&mask),
            [LENGTH, HEIGHT],
            40.0,
            220,
        )?;
        println!("wrote {}", path.display());
        let path = args.out.join("cylinder_2d2_lift.svg");
        write_history(&path, &history)?;
        println!("wrote {}", path.display());
        let costs = flow_common::step_costs(&scene, &s, args.pick(10, 3))?;
        out.insert(
            "2d2".into(),
            json!({
                "reference": iv, "runs": rows,
                "error_outside_interval": {"strouhal": est, "cd_max": ecd, "cl_max": ecl},
                "observed_order": {"strouhal": orders(&opt.cpd, &est), "cd_max": orders(&opt.cpd, &ecd), "cl_max": orders(&opt.cpd, &ecl)},
                "stated_cells_per_diameter": stated,
                "floor": {"strouhal_within": 0.05, "met": floor_met},
                "step_costs_at_stated_grid": costs,
            }),
        );
    }
    out.insert(
        "peak_rss_bytes".into(),
        json!(flow_common::peak_rss_bytes()),
    );
    common::print_json_line(&Value::Object(out));
    Ok(())
}

/// cD and cL over the recorded window.
fn write_history(path: &std::path::Path, history: &[[f64; 3]]) -> Result<()> {
    use plotters::prelude::*;
    if history.len() < 2 {
        return Ok(());
    }
    let (t0, t1) = (history[0][0], history[history.len() - 1][0]);
    let lo = history
        .iter()
        .flat_map(|h| [h[1], h[2]])
        .fold(f64::INFINITY, f64::min);
    let hi = history
        .iter()
        .flat_map(|h| [h[1], h[2]])
        .fold(f64::NEG_INFINITY, f64::max);
    let root = SVGBackend::new(path, (900, 360)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut c = ChartBuilder::on(&root)
        .caption("2D-2: drag and lift coefficients", ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(45)
        .build_cartesian_2d(t0..t1, (lo - 0.1)..(hi + 0.1))?;
    c.configure_mesh().x_desc("t").draw()?;
    let every = (history.len() / 2000).max(1);
    c.draw_series(LineSeries::new(
        history.iter().step_by(every).map(|h| (h[0], h[1])),
        &RED,
    ))?
    .label("cD")
    .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], RED));
    c.draw_series(LineSeries::new(
        history.iter().step_by(every).map(|h| (h[0], h[2])),
        &BLUE,
    ))?
    .label("cL")
    .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLUE));
    c.configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE)
        .draw()?;
    root.present()?;
    Ok(())
}
