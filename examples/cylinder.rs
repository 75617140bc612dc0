//! Flow around a cylinder in a channel: the DFG benchmark of Schaefer and
//! Turek (1996), test cases 2D-1 (Re = 20, steady) and 2D-2 (Re = 100,
//! periodic), beside the published reference intervals
//! (`diffphys::flow::validation::DFG_2D1`, `DFG_2D2`).
//!
//! The channel is 2.2 × 0.41, the cylinder of diameter D = 0.1 is centred at
//! (0.2, 0.2), ν = 1e-3, density 1; parabolic inflow of peak Um (0.3 for
//! 2D-1, 1.5 for 2D-2) on the left, outflow on the right, no-slip walls and
//! cylinder. The grid has `cpd` cells across the diameter (square cells of
//! h = D / cpd, 22 cpd x 4.1 cpd cells) and the cylinder is a staircase of
//! solid cells. MacCormack advection with the limiter, Courant number 0.4 at
//! Um, explicit viscosity where stable, implicit otherwise. The setup, the
//! runs and their analysis are the library's (`validation::DfgChannel`,
//! `Dfg2d1`, `Dfg2d2`); this example runs them over a refinement table and
//! charts the wake.
//!
//! - 2D-1: from the inflow profile extended through the channel, run until the
//!   velocity changes by less than `--tol` (1e-4) per unit time; drag and lift
//!   coefficients `cD = 2 F_x / (Ubar² D)`, `cL = 2 F_y / (Ubar² D)` (the
//!   force of the flow on the staircase body, pressure and wall shear), and the
//!   pressure difference `dp = p(0.15, 0.2) − p(0.25, 0.2)` (the pressure of
//!   the fluid cells next to the front and back points, extrapolated to them).
//!   The drag and lift are reported by two methods side by side: the surface
//!   integral over the staircase and the momentum balance over the square of
//!   half-width 0.1 about the centre (`validation::control_volume_force`,
//!   one box, the time term from one more step), each with its error and
//!   observed order.
//! - 2D-2: from the same start, run to `t_end`; over the last `window` time
//!   units, `max cD`, `max cL` and the Strouhal number `St = D f / Ubar` from
//!   the period of the lift (its up-crossings of the mean); max cD and max cL
//!   also by the momentum balance over the same square, its time term from
//!   successive states (second order at the half step).
//!
//! Each case runs at each grid of `--cpd` (a refinement table with the error
//! against the reference interval); the finest is the stated grid of the
//! floors: 2D-1 drag within 5 % of the interval, 2D-2 Strouhal within 5 %.
//! The example exits non-zero, after its JSON line, when a floor is missed.
//! A vorticity chart of the 2D-2 wake at its last step is written to
//! `OUT/cylinder_2d2_vorticity.svg`, the lift history to
//! `OUT/cylinder_2d2_lift.svg`. The last stdout line is the JSON of it all.
//!
//! `cargo run --release --example cylinder -- [--cpd 10,20] [--cases 2d1,2d2]
//! [--t-end 12] [--window 4] [--tol 1e-4] [--max-time 40] [--small] [--out DIR]`

mod common;
mod flow_common;

use std::time::Instant;

use diffphys::flow::diagnostics::vorticity;
use diffphys::flow::validation::{
    observed_orders, Dfg2d1, Dfg2d2, FaceBox, FloorCheck, Interval, DFG_2D1, DFG_2D2, DFG_HEIGHT,
    DFG_LENGTH,
};
use diffphys::flow::Scene;
use ndarray::Array2;
use serde_json::{json, Value};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// An interval as the JSON pair `[lo, hi]`.
fn pair(i: Interval) -> [f64; 2] {
    [i.lo, i.hi]
}

/// What the two force columns are, for the JSON.
const FORCE_METHODS: &str = "cd, cl: surface integral over the staircase (DfgChannel::coefficients); \
    *_cv: momentum balance over the square of half-width 0.1 about the centre (DfgChannel::control_box, \
    validation::control_volume_force), one box; 2D-2 time term from successive states";

/// A control box as the JSON `[i0, i1, j0, j1]`.
fn box_faces(b: FaceBox) -> [usize; 4] {
    [b.i0, b.i1, b.j0, b.j1]
}

/// Where the stated grid of the floors, the finest, stands in `cpd`.
fn stated_index(cpd: &[usize]) -> usize {
    let stated = cpd.iter().max();
    cpd.iter()
        .position(|c| Some(c) == stated)
        .expect("at least one grid")
}

/// Prints each quantity's relative distance outside its interval at each
/// grid and its observed orders between successive grids, then the floors
/// of the stated grid.
fn print_errors(cpd: &[usize], columns: &[(&str, &[f64])], floors: &[FloorCheck]) {
    let names: Vec<String> = columns
        .iter()
        .map(|(name, _)| format!("{name} error"))
        .collect();
    println!(
        "      cpd | {}   (relative distance outside the interval)",
        names.join(" | ")
    );
    for (k, c) in cpd.iter().enumerate() {
        let cells = columns
            .iter()
            .zip(&names)
            .map(|((_, e), name)| format!("{:>w$.2} %", e[k] * 1e2, w = name.len() - 2))
            .collect::<Vec<_>>();
        println!("  {c:>7} | {}", cells.join(" | "));
    }
    let orders: Vec<Vec<Option<f64>>> = columns
        .iter()
        .map(|(_, e)| observed_orders(cpd, e))
        .collect();
    for k in 1..cpd.len() {
        let cells = orders
            .iter()
            .zip(&names)
            .map(|(o, name)| match o[k - 1] {
                Some(p) => format!("{p:>w$.2}", w = name.len()),
                None => format!("{:>w$}", "-", w = name.len()),
            })
            .collect::<Vec<_>>();
        let pair = format!("{}-{}", cpd[k - 1], cpd[k]);
        println!("  {pair:>7} | {}   (observed order)", cells.join(" | "));
    }
    let stated = cpd[stated_index(cpd)];
    for f in floors {
        println!("  floor at cpd {stated}: {f}");
    }
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

/// The DFG 2D-1 and 2D-2 cylinder benchmarks against Schäfer and Turek's intervals.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    #[command(flatten)]
    opt: Options,
}

#[derive(clap::Args)]
struct Options {
    /// Grids, as cells across the cylinder's diameter, at least 4 each (8 with
    /// --small).
    #[arg(long, value_name = "LIST", value_delimiter = ',', default_values_t = [10, 20],
          default_value_if("small", "true", "8"))]
    cpd: Vec<usize>,
    /// Cases: the steady 2D-1 (Re 20) and the periodic 2D-2 (Re 100).
    #[arg(long, value_name = "LIST", value_delimiter = ',', ignore_case = true,
          value_parser = ["2d1", "2d2"], default_values_t = ["2d1".to_string(), "2d2".to_string()])]
    cases: Vec<String>,
    /// 2D-2: time units simulated (3 with --small).
    #[arg(
        long,
        value_name = "T",
        default_value_t = 12.0,
        default_value_if("small", "true", "3")
    )]
    t_end: f64,
    /// 2D-2: the last time units measured, in (0, t-end) (1.5 with --small).
    #[arg(
        long,
        value_name = "T",
        default_value_t = 4.0,
        default_value_if("small", "true", "1.5")
    )]
    window: f64,
    /// 2D-1: time units before the run stops unsteady (8 with --small).
    #[arg(
        long,
        value_name = "T",
        default_value_t = 40.0,
        default_value_if("small", "true", "8")
    )]
    max_time: f64,
    /// 2D-1: steady when the velocity changes by less than this per unit time.
    #[arg(long, default_value_t = 1e-4)]
    tol: f64,
}

fn parse() -> Result<(common::ExampleArgs, Options)> {
    let Cli { common, mut opt } = common::parse_args("cylinder")?;
    if opt.cpd.iter().any(|&c| c < 4) {
        return Err("--cpd: at least 4 cells across the diameter".into());
    }
    opt.cases.iter_mut().for_each(|c| *c = c.to_lowercase());
    if !(opt.window > 0.0 && opt.window < opt.t_end) {
        return Err(format!("--window must lie in (0, t_end = {})", opt.t_end).into());
    }
    Ok((common, opt))
}

fn main() -> Result<()> {
    let (args, opt) = parse()?;
    let mut out = serde_json::Map::new();
    out.insert("cells_per_diameter".into(), json!(opt.cpd));
    let stated = *opt.cpd.iter().max().expect("at least one grid");
    let mut floors = Vec::new();

    if opt.cases.iter().any(|c| c == "2d1") {
        let iv = DFG_2D1;
        println!(
            "2D-1 (Re = 20, steady): reference cD {:?}, cL {:?}, dp {:?}",
            pair(iv.cd),
            pair(iv.cl),
            pair(iv.dp)
        );
        let mut rows = Vec::new();
        let mut results = Vec::new();
        for &cpd in &opt.cpd {
            let mut case = Dfg2d1::new(cpd)?;
            (case.tol, case.max_time) = (opt.tol, opt.max_time);
            let t0 = Instant::now();
            let r = case.run(&mut |_, _, _| Ok(()))?;
            let seconds = t0.elapsed().as_secs_f64();
            let ([cd, cl, dp], [cd_cv, cl_cv], run) = (r.values, r.control_volume, &r.run);
            println!(
                "  2D-1 cpd {cpd:3}: surface cD {cd:.4}  cL {cl:+.5}; control volume cD {cd_cv:.4}  cL {cl_cv:+.5}; dp {dp:.4}  ({} steps to t = {:.2}, {}; {seconds:.1} s, {:.2} ms/step)",
                run.steps,
                run.time,
                if run.steady { "steady" } else { "NOT steady" },
                seconds / run.steps as f64 * 1e3
            );
            rows.push(json!({
                "grid": grid_json(&r.scene, cpd), "cd": cd, "cl": cl, "dp": dp,
                "cd_cv": cd_cv, "cl_cv": cl_cv, "cv_box_faces": box_faces(r.cv_box),
                "steady": run.steady, "tol": opt.tol, "rate_at_end": run.rate, "steps": run.steps,
                "substeps": run.substeps, "time": run.time, "wall_s": seconds,
                "ms_per_step": seconds / run.steps as f64 * 1e3,
            }));
            results.push(r);
        }
        let err = |k: usize| -> Vec<f64> { results.iter().map(|r| r.errors[k]).collect() };
        let (ecd, ecl, edp) = (err(0), err(1), err(2));
        let cv_err =
            |k: usize| -> Vec<f64> { results.iter().map(|r| r.control_volume_errors[k]).collect() };
        let (ecd_cv, ecl_cv) = (cv_err(0), cv_err(1));
        let case_floors = &results[stated_index(&opt.cpd)].floors;
        print_errors(
            &opt.cpd,
            &[
                ("cD", &ecd),
                ("CV cD", &ecd_cv),
                ("cL", &ecl),
                ("CV cL", &ecl_cv),
                ("dp", &edp),
            ],
            case_floors,
        );
        let last = results.last().expect("one grid at least");
        let costs = flow_common::step_costs(&last.scene, &last.run.state, args.pick(10, 3))?;
        out.insert(
            "2d1".into(),
            json!({
                "reference": {"cd": pair(iv.cd), "cl": pair(iv.cl), "dp": pair(iv.dp)}, "runs": rows,
                "force_methods": FORCE_METHODS,
                "error_outside_interval": {"cd": ecd, "cl": ecl, "dp": edp, "cd_cv": ecd_cv, "cl_cv": ecl_cv},
                "observed_order": {"cd": observed_orders(&opt.cpd, &ecd), "cl": observed_orders(&opt.cpd, &ecl), "dp": observed_orders(&opt.cpd, &edp),
                                   "cd_cv": observed_orders(&opt.cpd, &ecd_cv), "cl_cv": observed_orders(&opt.cpd, &ecl_cv)},
                "stated_cells_per_diameter": stated,
                "floor": flow_common::floors_json(case_floors),
                "step_costs_at_stated_grid": costs,
            }),
        );
        floors.extend_from_slice(case_floors);
    }

    if opt.cases.iter().any(|c| c == "2d2") {
        let iv = DFG_2D2;
        println!(
            "2D-2 (Re = 100, periodic): reference St {:?}, max cD {:?}, max cL {:?}; t_end {}, window {}",
            pair(iv.strouhal),
            pair(iv.cd_max),
            pair(iv.cl_max),
            opt.t_end,
            opt.window
        );
        let mut rows = Vec::new();
        let mut results = Vec::new();
        for &cpd in &opt.cpd {
            let mut case = Dfg2d2::new(cpd)?;
            (case.t_end, case.window) = (opt.t_end, opt.window);
            let t0 = Instant::now();
            let r = case.run()?;
            let seconds = t0.elapsed().as_secs_f64();
            let [steps, substeps] = r.steps;
            println!(
                "  2D-2 cpd {cpd:3}: St {:.4}  max cD {:.4} (CV {:.4})  max cL {:.4} (CV {:.4})  ({} lift periods in the last {} time units, {}; {steps} steps, {seconds:.1} s, {:.2} ms/step)",
                r.strouhal,
                r.cd_max,
                r.cd_max_cv,
                r.cl_max,
                r.cl_max_cv,
                r.periods.len(),
                opt.window,
                if r.periodic { "periodic" } else { "NOT yet periodic" },
                seconds / steps as f64 * 1e3
            );
            rows.push(json!({
                "grid": grid_json(&r.scene, cpd), "strouhal": r.strouhal, "cd_max": r.cd_max,
                "cl_max": r.cl_max, "cd_max_cv": r.cd_max_cv, "cl_max_cv": r.cl_max_cv,
                "cv_box_faces": box_faces(r.cv_box), "cl_min": r.cl_min, "cl_mean": r.cl_mean, "periods": r.periods,
                "periodic": r.periodic, "steps": steps, "substeps": substeps, "t_end": opt.t_end,
                "window": opt.window, "wall_s": seconds, "ms_per_step": seconds / steps as f64 * 1e3,
            }));
            results.push(r);
        }
        let err = |k: usize| -> Vec<f64> { results.iter().map(|r| r.errors[k]).collect() };
        let (est, ecd, ecl) = (err(0), err(1), err(2));
        let cv_err = |k: usize| -> Vec<f64> { results.iter().map(|r| r.cv_errors[k]).collect() };
        let (ecd_cv, ecl_cv) = (cv_err(0), cv_err(1));
        let case_floors = &results[stated_index(&opt.cpd)].floors;
        print_errors(
            &opt.cpd,
            &[
                ("St", &est),
                ("max cD", &ecd),
                ("CV max cD", &ecd_cv),
                ("max cL", &ecl),
                ("CV max cL", &ecl_cv),
            ],
            case_floors,
        );
        let last = results.last().expect("one grid at least");
        let (scene, s) = (&last.scene, &last.state);
        let omega = vorticity(scene, s.ux.view(), s.uy.view())?;
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
            [DFG_LENGTH, DFG_HEIGHT],
            40.0,
            220,
        )?;
        println!("wrote {}", path.display());
        let path = args.out.join("cylinder_2d2_lift.svg");
        write_history(&path, &last.history)?;
        println!("wrote {}", path.display());
        let costs = flow_common::step_costs(scene, s, args.pick(10, 3))?;
        out.insert(
            "2d2".into(),
            json!({
                "reference": {"strouhal": pair(iv.strouhal), "cd_max": pair(iv.cd_max),
                              "cl_max": pair(iv.cl_max), "dp_half_period": pair(iv.dp_half_period)},
                "runs": rows,
                "force_methods": FORCE_METHODS,
                "error_outside_interval": {"strouhal": est, "cd_max": ecd, "cl_max": ecl, "cd_max_cv": ecd_cv, "cl_max_cv": ecl_cv},
                "observed_order": {"strouhal": observed_orders(&opt.cpd, &est), "cd_max": observed_orders(&opt.cpd, &ecd), "cl_max": observed_orders(&opt.cpd, &ecl),
                                   "cd_max_cv": observed_orders(&opt.cpd, &ecd_cv), "cl_max_cv": observed_orders(&opt.cpd, &ecl_cv)},
                "stated_cells_per_diameter": stated,
                "floor": flow_common::floors_json(case_floors),
                "step_costs_at_stated_grid": costs,
            }),
        );
        floors.extend_from_slice(case_floors);
    }
    out.insert(
        "peak_rss_bytes".into(),
        json!(flow_common::peak_rss_bytes()),
    );
    common::print_json_line(&Value::Object(out));
    flow_common::require_floors(&format!("cylinder at cpd {stated}"), &floors)
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
