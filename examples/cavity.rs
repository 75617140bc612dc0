//! The lid-driven cavity, run to steady state and compared with the table of
//! Ghia, Ghia and Shin (J. Comput. Phys. 48, 1982): the library's
//! `diffphys::flow::validation::Cavity` and its constants `GHIA_1982`.
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
//! per-step time, `peak_rss_bytes`. A value the library flags as suspect (a
//! likely misprint in Ghia's table) is shown and reported on its own but left
//! out of the largest deviation. A chart of both profiles against the table is
//! written to `OUT/cavity_re{Re}_n{n}.svg`, the JSON line to
//! `OUT/cavity_re{Re}_n{n}.json`; `--overlay-n 64,256` also draws the profiles
//! of earlier runs at those grids from their JSON files in `OUT` (a refinement
//! figure).
//!
//! Floor (the flow-step issue): at 128 x 128 and Re = 100, |u − u_Ghia| ≤ 0.02
//! at every tabulated point.
//!
//! `cargo run --release --example cavity -- [--re 100|400|1000] [--n 128]
//! [--tol 1e-4] [--max-time T] [--overlay-n 64,256] [--small] [--out DIR]`

mod common;
mod flow_common;

use std::time::Instant;

use diffphys::flow::validation::{Cavity, GhiaTable, GHIA_X, GHIA_Y};
use serde_json::{json, Value};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// The centrelines of a run, `(y, u, x, v)` as in its JSON.
type Profiles = (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>);

/// Which centreline of a run a chart panel draws.
type Line = dyn Fn(&Profiles) -> (&Vec<f64>, &Vec<f64>);

fn earlier_run(path: &std::path::Path) -> Result<Profiles> {
    let text = std::fs::read_to_string(path).map_err(|e| {
        format!(
            "--overlay-n: {} (written by a run at that grid): {e}",
            path.display()
        )
    })?;
    let run: Value = serde_json::from_str(&text)?;
    let numbers = |v: &Value| -> Result<Vec<f64>> {
        v.as_array()
            .ok_or_else(|| format!("{}: no centrelines", path.display()))?
            .iter()
            .map(|x| x.as_f64().ok_or_else(|| "not a number".into()))
            .collect()
    };
    Ok((
        numbers(&run["centerline_u"]["y"])?,
        numbers(&run["centerline_u"]["u"])?,
        numbers(&run["centerline_v"]["x"])?,
        numbers(&run["centerline_v"]["v"])?,
    ))
}

/// The lid-driven cavity to steady state against Ghia, Ghia and Shin's table.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    #[command(flatten)]
    opt: Options,
}

#[derive(clap::Args)]
struct Options {
    /// Reynolds number: 100, 400 or 1000 (Ghia's table).
    #[arg(long, default_value_t = 100)]
    re: u32,
    /// Cells per side, even and at least 8 (32 with --small).
    #[arg(long, default_value_t = 128, default_value_if("small", "true", "32"))]
    n: usize,
    /// Steady when the velocity changes by less than this per unit time.
    #[arg(long, default_value_t = 1e-4)]
    tol: f64,
    /// Lid time units before the run stops unsteady [default: 40 at Re <= 150,
    /// 80 at Re <= 500, else 160].
    #[arg(long, value_name = "T")]
    max_time: Option<f64>,
    /// Grids of earlier runs (their JSON files in OUT) to draw beside this one
    /// [default: none].
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    overlay_n: Vec<usize>,
}

fn parse() -> Result<(common::ExampleArgs, Options)> {
    let Cli { common, opt } = common::parse_args("cavity")?;
    if opt.n < 8 || opt.n % 2 != 0 {
        return Err(format!("--n must be even and at least 8, got {}", opt.n).into());
    }
    Ok((common, opt))
}

fn main() -> Result<()> {
    let (args, opt) = parse()?;
    let mut cavity = Cavity::new(opt.re, opt.n)?.tol(opt.tol);
    if let Some(t) = opt.max_time {
        cavity = cavity.max_time(t);
    }
    let table = GhiaTable::at(opt.re).expect("Cavity::new checked Re");
    let chart_name = |n: usize, ext: &str| format!("cavity_re{}_n{n}.{ext}", opt.re);
    // read the earlier runs first: a missing file is an error before the run
    let overlays = opt
        .overlay_n
        .iter()
        .map(|&n| Ok((n, earlier_run(&args.out.join(chart_name(n, "json")))?)))
        .collect::<Result<Vec<_>>>()?;
    let (stop, dt) = (cavity.stop(), cavity.dt());
    println!(
        "lid-driven cavity, Re = {}, {} x {} cells, dt = {dt:.3e}; to d|u|/dt < {:.0e} or t = {}",
        opt.re, opt.n, opt.n, stop.tol, stop.max_time
    );

    let t0 = Instant::now();
    let result = cavity.run_observed(&mut |steps, _, rate| {
        if steps % (20 * stop.window) == 0 {
            println!(
                "  t = {:7.2}  steps {steps:6}  d|u|/dt = {rate:.2e}",
                steps as f64 * dt
            );
        }
        Ok(())
    })?;
    let seconds = t0.elapsed().as_secs_f64();
    let (run, settings) = (&result.run, result.scene.settings());
    let mode = result.viscosity_mode;
    println!(
        "  {mode:?} viscosity, {:?} pressure",
        settings.pressure_solver
    );

    let (y, u) = &result.centreline_u;
    let (x, v) = &result.centreline_v;
    let (u_at, v_at) = (&result.ghia_u, &result.ghia_v);
    let dev = |ours: &[f64], theirs: &[f64]| -> Vec<f64> {
        ours.iter()
            .zip(theirs)
            .map(|(a, b)| (a - b).abs())
            .collect()
    };
    let (du, dv) = (dev(u_at, &table.u), dev(v_at, &table.v));
    let (max_du, max_dv) = (result.max_deviation_u, result.max_deviation_v);
    let suspect_points: Vec<Value> = result
        .suspect
        .iter()
        .map(|p| json!({"line": "v", "x": p.x, "ours": p.ours, "ghia": p.ghia, "abs_deviation": (p.ours - p.ghia).abs()}))
        .collect();
    // The floors that apply at this Re and grid (Re 100 on 32 x 32 against
    // Ghia's own accuracy, on 128 x 128 the flow step's), from the library.
    let floors = &result.floors;

    println!("   y       u (ours)   u (Ghia)   |diff|      x       v (ours)   v (Ghia)   |diff|");
    for k in 0..GHIA_Y.len() {
        println!(
            "  {:.4}  {:+.5}  {:+.5}  {:.5}     {:.4}  {:+.5}  {:+.5}  {:.5}{}",
            GHIA_Y[k],
            u_at[k],
            table.u[k],
            du[k],
            GHIA_X[k],
            v_at[k],
            table.v[k],
            dv[k],
            if table.v_suspect == Some(k) { "*" } else { " " }
        );
    }
    if !suspect_points.is_empty() {
        println!("  * flagged as suspect (a likely misprint): not in the maxima below");
    }
    println!(
        "Re = {}: max |u - u_Ghia| = {max_du:.4}, max |v - v_Ghia| = {max_dv:.4}; {} steps to t = {:.2} \
         ({}), {seconds:.1} s ({:.3} ms per step)",
        opt.re,
        run.steps,
        run.time,
        if run.steady { "steady" } else { "NOT steady: the time limit came first" },
        seconds / run.steps as f64 * 1e3
    );
    for f in floors {
        println!("floor: {f}");
    }
    let chart = args.out.join(chart_name(opt.n, "svg"));
    let ours = (y.clone(), u.clone(), x.clone(), v.clone());
    write_chart(&chart, opt.re, (opt.n, &ours), &overlays, table)?;
    println!("wrote {}", chart.display());

    let line = json!({
        "re": opt.re, "n": opt.n, "dt": result.dt, "viscosity_mode": format!("{mode:?}"),
        "pressure_solver": format!("{:?}", settings.pressure_solver),
        "advection": format!("{:?}", settings.advection),
        "centerline_u": {"y": y, "u": u},
        "centerline_v": {"x": x, "v": v},
        "ghia": {
            "y": GHIA_Y, "u_ours": u_at, "u_ghia": table.u,
            "x": GHIA_X, "v_ours": v_at, "v_ghia": table.v,
        },
        "max_abs_u_deviation": max_du, "max_abs_v_deviation": max_dv,
        "suspect_points": suspect_points,
        "floor": flow_common::floors_json(floors),
        "steady": run.steady, "rate_at_end": run.rate, "tol": stop.tol,
        "steps": run.steps, "time": run.time, "wall_s": seconds,
        "ms_per_step": seconds / run.steps as f64 * 1e3,
        "pressure_iterations_per_step": run.pressure_iterations as f64 / run.steps as f64,
        "peak_rss_bytes": flow_common::peak_rss_bytes(),
    });
    let path = args.out.join(chart_name(opt.n, "json"));
    std::fs::write(&path, serde_json::to_string(&line)?)?;
    println!("wrote {}", path.display());
    common::print_json_line(&line);
    flow_common::require_floors(&format!("Re {} on {} x {}", opt.re, opt.n, opt.n), floors)
}

fn write_chart(
    path: &std::path::Path,
    re: u32,
    (n, ours): (usize, &Profiles),
    overlays: &[(usize, Profiles)],
    table: &GhiaTable,
) -> Result<()> {
    use plotters::prelude::*;
    let v_suspect: [bool; 17] = std::array::from_fn(|k| table.v_suspect == Some(k));
    // the other grids' colours, in the order given
    const OTHERS: [RGBColor; 3] = [RGBColor(0, 150, 60), RGBColor(200, 120, 0), BLACK];
    let grids = std::iter::once(n)
        .chain(overlays.iter().map(|o| o.0))
        .map(|m| format!("{m}x{m}"))
        .collect::<Vec<_>>()
        .join(", ");
    let root = SVGBackend::new(path, (900, 440)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(450);
    // one panel: the profile (coordinate, value) pairs drawn as (a, b) by `xy`
    let panel = |area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
                 caption: String,
                 (xr, yr): (std::ops::Range<f64>, std::ops::Range<f64>),
                 (x_desc, y_desc): (&str, &str),
                 pick: &Line,
                 points: (&[f64], &[f64], &[bool]),
                 xy: &dyn Fn(f64, f64) -> (f64, f64),
                 legend: Option<SeriesLabelPosition>|
     -> Result<()> {
        let mut c = ChartBuilder::on(area)
            .caption(caption, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(xr, yr)?;
        c.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw()?;
        for (k, (m, profiles)) in overlays.iter().enumerate() {
            let colour = OTHERS[k % OTHERS.len()];
            let (s, f) = pick(profiles);
            c.draw_series(DashedLineSeries::new(
                s.iter().zip(f).map(|(&a, &b)| xy(a, b)),
                6,
                4,
                colour.stroke_width(1),
            ))?
            .label(format!("diffphys-flow {m}x{m}"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour));
        }
        let (s, f) = pick(ours);
        c.draw_series(LineSeries::new(
            s.iter().zip(f).map(|(&a, &b)| xy(a, b)),
            BLUE.stroke_width(2),
        ))?
        .label(format!("diffphys-flow {n}x{n}"))
        .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLUE.stroke_width(2)));
        let (coords, values, suspect) = points;
        let at = |keep: bool| {
            coords
                .iter()
                .zip(values)
                .zip(suspect)
                .filter(move |(_, &s)| s != keep)
                .map(|((&a, &b), _)| xy(a, b))
        };
        c.draw_series(at(true).map(|p| Circle::new(p, 4, RED.stroke_width(2))))?
            .label("Ghia et al. 1982")
            .legend(|(x, y)| Circle::new((x + 8, y), 4, RED.stroke_width(2)));
        if suspect.iter().any(|&s| s) {
            c.draw_series(at(false).map(|p| Cross::new(p, 5, BLACK.stroke_width(2))))?
                .label("Ghia, flagged suspect")
                .legend(|(x, y)| Cross::new((x + 8, y), 5, BLACK.stroke_width(2)));
        }
        if let Some(at) = legend {
            c.configure_series_labels()
                .position(at)
                .border_style(BLACK)
                .background_style(WHITE)
                .draw()?;
        }
        Ok(())
    };
    panel(
        &left,
        format!("u along x = 0.5, Re = {re}, {grids}"),
        (-0.6..1.05, 0.0..1.0),
        ("u / U", "y"),
        &|p: &Profiles| (&p.0, &p.1),
        (&GHIA_Y, &table.u, &[false; 17]),
        &|y, u| (u, y),
        Some(SeriesLabelPosition::LowerRight),
    )?;
    panel(
        &right,
        format!("v along y = 0.5, Re = {re}, {grids}"),
        (0.0..1.0, -0.6..0.45),
        ("x", "v / U"),
        &|p: &Profiles| (&p.2, &p.3),
        (&GHIA_X, &table.v, &v_suspect),
        &|x, v| (x, v),
        // the legend again where it explains the suspect marker
        table
            .v_suspect
            .is_some()
            .then_some(SeriesLabelPosition::UpperRight),
    )?;
    root.present()?;
    Ok(())
}
