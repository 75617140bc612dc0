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
//! per-step time, `peak_rss_bytes`. A value the data file flags as suspect (a
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

use std::path::PathBuf;
use std::time::Instant;

use diffphys::flow::validation::Cavity;
use diffphys::flow::{Advection, FlowState, Scene, Sides, ViscosityMode};
use ndarray::Array2;
use serde_json::{json, Value};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

const LID: f64 = 1.0;

/// Ghia's table for one Reynolds number.
struct Ghia {
    y: Vec<f64>,
    u: Vec<f64>,
    x: Vec<f64>,
    v: Vec<f64>,
    /// Whether each point of `u` (`v`) is flagged as suspect in the data file.
    u_suspect: Vec<bool>,
    v_suspect: Vec<bool>,
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
    let (y, x) = (numbers(&u["y"])?, numbers(&v["x"])?);
    // the points `suspect` names for this Re in one table, by coordinate
    let suspect = |name: &str, coords: &[f64]| -> Vec<bool> {
        let flagged: Vec<f64> = table["suspect"]
            .as_array()
            .into_iter()
            .flatten()
            .filter(|s| s["table"] == name && s["re"].as_u64() == Some(re as u64))
            .filter_map(|s| s["x"].as_f64().or_else(|| s["y"].as_f64()))
            .collect();
        coords
            .iter()
            .map(|c| flagged.iter().any(|f| (f - c).abs() < 1e-9))
            .collect()
    };
    Ok(Ghia {
        u_suspect: suspect("u_along_vertical_centreline", &y),
        v_suspect: suspect("v_along_horizontal_centreline", &x),
        y,
        u: numbers(&u[&key])?,
        x,
        v: numbers(&v[&key])?,
    })
}

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
    let table = ghia(opt.re)?;
    let chart_name = |n: usize, ext: &str| format!("cavity_re{}_n{n}.{ext}", opt.re);
    // read the earlier runs first: a missing file is an error before the run
    let overlays = opt
        .overlay_n
        .iter()
        .map(|&n| Ok((n, earlier_run(&args.out.join(chart_name(n, "json")))?)))
        .collect::<Result<Vec<_>>>()?;
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
    // the largest deviation over the points not flagged as suspect
    let worst = |d: &[f64], suspect: &[bool]| {
        d.iter()
            .zip(suspect)
            .filter(|(_, &s)| !s)
            .fold(0.0f64, |m, (&x, _)| m.max(x))
    };
    let (max_du, max_dv) = (worst(&du, &table.u_suspect), worst(&dv, &table.v_suspect));
    let suspect_points: Vec<Value> = (0..table.y.len())
        .filter(|&k| table.u_suspect[k])
        .map(|k| json!({"line": "u", "y": table.y[k], "ours": u_at[k], "ghia": table.u[k], "abs_deviation": du[k]}))
        .chain(
            (0..table.x.len())
                .filter(|&k| table.v_suspect[k])
                .map(|k| json!({"line": "v", "x": table.x[k], "ours": v_at[k], "ghia": table.v[k], "abs_deviation": dv[k]})),
        )
        .collect();
    // The floors that apply at this Re and grid (Re 100 on 32 x 32 against
    // Ghia's own accuracy, on 128 x 128 the flow step's), from the library.
    let floors = Cavity::new(opt.re, opt.n)?.floors((max_du, max_dv));
    let floor_met = floors.iter().all(|f| f.met());

    println!("   y       u (ours)   u (Ghia)   |diff|      x       v (ours)   v (Ghia)   |diff|");
    let mark = |s: bool| if s { "*" } else { " " };
    for k in 0..table.y.len() {
        println!(
            "  {:.4}  {:+.5}  {:+.5}  {:.5}{}    {:.4}  {:+.5}  {:+.5}  {:.5}{}",
            table.y[k],
            u_at[k],
            table.u[k],
            du[k],
            mark(table.u_suspect[k]),
            table.x[k],
            v_at[k],
            table.v[k],
            dv[k],
            mark(table.v_suspect[k])
        );
    }
    if !suspect_points.is_empty() {
        println!(
            "  * flagged as suspect in the data file (a likely misprint): not in the maxima below"
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
    for f in &floors {
        println!("floor: {f}");
    }
    let chart = args.out.join(chart_name(opt.n, "svg"));
    let ours = (y.clone(), u.clone(), x.clone(), v.clone());
    write_chart(&chart, opt.re, (opt.n, &ours), &overlays, &table)?;
    println!("wrote {}", chart.display());

    let line = json!({
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
        "suspect_points": suspect_points,
        "floor": if floors.is_empty() { Value::Null } else { json!({"checks": floors.iter().map(|f| f.to_string()).collect::<Vec<_>>(), "met": floor_met}) },
        "steady": steady, "rate_at_end": rate, "tol": opt.tol,
        "steps": steps, "time": steps as f64 * dt, "wall_s": seconds,
        "ms_per_step": seconds / steps as f64 * 1e3,
        "pressure_iterations_per_step": pressure_iterations as f64 / steps as f64,
        "peak_rss_bytes": flow_common::peak_rss_bytes(),
    });
    let path = args.out.join(chart_name(opt.n, "json"));
    std::fs::write(&path, serde_json::to_string(&line)?)?;
    println!("wrote {}", path.display());
    common::print_json_line(&line);
    if !floor_met {
        return Err(format!(
            "Re {} on {} x {}: a published floor is not met",
            opt.re, opt.n, opt.n
        )
        .into());
    }
    Ok(())
}

fn write_chart(
    path: &std::path::Path,
    re: u32,
    (n, ours): (usize, &Profiles),
    overlays: &[(usize, Profiles)],
    table: &Ghia,
) -> Result<()> {
    use plotters::prelude::*;
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
        (&table.y, &table.u, &table.u_suspect),
        &|y, u| (u, y),
        Some(SeriesLabelPosition::LowerRight),
    )?;
    panel(
        &right,
        format!("v along y = 0.5, Re = {re}, {grids}"),
        (0.0..1.0, -0.6..0.45),
        ("x", "v / U"),
        &|p: &Profiles| (&p.2, &p.3),
        (&table.x, &table.v, &table.v_suspect),
        &|x, v| (x, v),
        // the legend again where it explains the suspect marker
        table
            .v_suspect
            .iter()
            .any(|&s| s)
            .then_some(SeriesLabelPosition::UpperRight),
    )?;
    root.present()?;
    Ok(())
}
