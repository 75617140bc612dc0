//! The harness's charts from its rows.

use std::path::Path;

use crate::chart::{line_chart_svg, LineChart, Series};
use crate::model::{Method, ResultRow};
use crate::problem::OperatorKind;

const MIB: f64 = 1024.0 * 1024.0;

pub(crate) fn write_chart(
    out_dir: &Path,
    file: &str,
    caption: &str,
    chart: LineChart<'_>,
    charts: &mut Vec<(String, String)>,
    notes: &mut Vec<String>,
) {
    match line_chart_svg(&out_dir.join(file), &chart) {
        Ok(()) => charts.push((file.to_string(), caption.to_string())),
        Err(e) => notes.push(format!("chart {file} not drawn: {e}")),
    }
}

/// Groups `rows` into one series per `method precision`, in a fixed method order
/// so colours match across charts.
pub(crate) fn series_by_method<'a>(
    rows: impl Iterator<Item = &'a ResultRow>,
    point: impl Fn(&ResultRow) -> Option<(f64, f64)>,
) -> Vec<Series> {
    // (method order, label) → points
    type Group = ((Method, String), Vec<(f64, f64)>);
    let mut groups: Vec<Group> = Vec::new();
    for r in rows {
        let Some(p) = point(r) else { continue };
        let key = (r.method, r.series_label());
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, pts)) => pts.push(p),
            None => groups.push((key, vec![p])),
        }
    }
    groups.sort_by(|a, b| a.0.cmp(&b.0));
    groups
        .into_iter()
        .map(|((_, label), mut pts)| {
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series::new(label, pts)
        })
        .collect()
}

/// Draws the harness's charts into `out_dir` from `rows`: gradient error vs
/// time, gradient error vs the reached residual of tolerance runs, peak memory
/// vs iterations, time vs grid size, CG iterations vs grid size (plain CG
/// against MG-PCG), and the stability map
/// (error, or non-finite, against fixed iteration counts). Returns the charts
/// drawn (file, caption) and notes on those that could not be.
pub fn write_charts(out_dir: &Path, rows: &[ResultRow]) -> (Vec<(String, String)>, Vec<String>) {
    let mut charts = Vec::new();
    let mut notes = Vec::new();
    let laplacian = OperatorKind::Laplacian;
    // Per-size charts use the largest size at which the naive method ran.
    let chart_n = rows
        .iter()
        .filter(|r| r.method == Method::Naive && r.error.is_none() && r.operator == laplacian)
        .map(|r| r.n)
        .max()
        .or_else(|| rows.iter().map(|r| r.n).max())
        .unwrap_or(0);
    let gradient_rows = || {
        rows.iter()
            .filter(move |r| r.n == chart_n && r.operator == laplacian)
            .filter(|r| r.method != Method::BaselineCg)
    };

    let caption = format!("Gradient error vs time ({chart_n}², laplacian)");
    // The exact f64 row has error 0, which a log axis cannot place.
    let series = series_by_method(
        gradient_rows().filter(|r| r.grad_rel_err.is_some_and(|e| e > 0.0)),
        |r| Some((r.total_s()?, r.grad_rel_err?)),
    );
    write_chart(
        out_dir,
        "error_vs_time.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "forward + backward time (s)",
            y_label: "relative gradient error vs exact",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    // Tolerance runs placed at the residual they reached, not the one asked
    // for: below the rounding floor of a precision the two differ.
    let caption = format!("Gradient error vs reached residual ({chart_n}², laplacian)");
    let series = series_by_method(
        gradient_rows().filter(|r| {
            r.rtol.is_some() && r.grad_rel_err.is_some_and(|e| e > 0.0) && r.method != Method::Exact
        }),
        |r| Some((r.reached_relative_residual?, r.grad_rel_err?)),
    );
    write_chart(
        out_dir,
        "error_vs_residual.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "reached relative residual ‖b − A p‖/‖b‖ (tolerance runs)",
            y_label: "relative gradient error vs exact",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = format!("Peak heap vs CG iterations ({chart_n}², laplacian)");
    let series = series_by_method(
        gradient_rows().filter(|r| r.rtol.is_none() && r.method != Method::Exact),
        |r| Some((r.iterations? as f64, r.peak_heap_bytes? as f64 / MIB)),
    );
    write_chart(
        out_dir,
        "memory_vs_iterations.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "CG iterations",
            y_label: "peak heap (MiB)",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let tightest = rows
        .iter()
        .filter_map(|r| r.rtol)
        .fold(f64::INFINITY, f64::min);
    let caption = format!("Gradient time vs grid size (laplacian, rtol {tightest:e})");
    let series = series_by_method(
        // The baseline is forward-only; its comparison is the per-iteration floor.
        rows.iter().filter(|r| {
            r.operator == laplacian
                && r.method != Method::BaselineCg
                && (r.rtol == Some(tightest) || r.method == Method::Exact)
        }),
        |r| Some((r.n as f64, r.total_s()?)),
    );
    write_chart(
        out_dir,
        "time_vs_size.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "grid size n (n × n cells)",
            y_label: "forward + backward time (s)",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = format!("CG iterations vs grid size (laplacian, rtol {tightest:e})");
    let series = series_by_method(
        rows.iter().filter(|r| {
            r.operator == laplacian
                && r.rtol == Some(tightest)
                && r.error.is_none()
                && matches!(r.method, Method::Implicit | Method::ImplicitMgpcg)
        }),
        |r| Some((r.n as f64, r.iterations? as f64)),
    );
    write_chart(
        out_dir,
        "iterations_vs_size.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "grid size n (n × n cells)",
            y_label: "forward CG iterations to the tolerance",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption =
        format!("Stability: gradient error vs fixed CG iterations ({chart_n}², laplacian)");
    let series = series_by_method(
        gradient_rows().filter(|r| r.rtol.is_none() && r.method != Method::Exact),
        |r| {
            let iters = r.max_iters? as f64;
            let shown = if r.finite { r.grad_rel_err? } else { f64::NAN };
            Some((iters, shown))
        },
    );
    write_chart(
        out_dir,
        "stability.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "CG iterations",
            y_label: "relative gradient error (× = non-finite)",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );
    (charts, notes)
}
