//! A stability run out to files and stdout: charts, JSON, markdown, tables and
//! the key-figure line.

use std::path::Path;

use crate::chart::{LineChart, Series};
use crate::harness::{series_by_method, write_chart};
use crate::model::{Method, Precision, ResultRow};
use crate::problem::OperatorKind;
use crate::{CompareError, Result};

use super::findings::first_failure;
use super::findings::{fmt, study};
use super::{StabilityResults, Study, UnrollRow, F32_FLOOR_LIMIT};

/// The rows of the CG studies, for the table and `report.md`.
pub fn result_rows(results: &StabilityResults, study_name: Study) -> Vec<ResultRow> {
    results
        .rows
        .iter()
        .filter(|r| r.study == study_name)
        .map(|r| {
            let mut row = r.row.clone();
            row.variant = r.variant.clone();
            row
        })
        .collect()
}

/// Draws the stability charts into `out_dir`; returns the charts drawn (file,
/// caption) and notes on those that could not be.
pub fn write_stability_charts(
    out_dir: &Path,
    results: &StabilityResults,
) -> (Vec<(String, String)>, Vec<String>) {
    let mut charts = Vec::new();
    let mut notes = Vec::new();
    let n = results.config.iteration_n;

    let caption = format!(
        "Stability: gradient error vs fixed CG iterations ({n}², laplacian; × = non-finite)"
    );
    let series = series_by_method(study(&results.rows, Study::Iterations), |r| {
        let shown = if r.finite && r.error.is_none() {
            r.grad_rel_err?
        } else {
            f64::NAN
        };
        Some((r.max_iters? as f64, shown))
    });
    write_chart(
        out_dir,
        "stability_iterations.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "CG iterations",
            y_label: "relative gradient error vs f64 exact",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = format!(
        "Gradient error vs forward relative residual ({}², f64)",
        results.config.unconverged_n
    );
    let mut series = Vec::new();
    for variant in ["adjoint tight", "adjoint alike"] {
        let pts = results
            .rows
            .iter()
            .filter(|r| r.study == Study::Unconverged && r.variant.as_deref() == Some(variant))
            .filter_map(|r| Some((r.row.reached_relative_residual?, r.row.grad_rel_err?)))
            .collect();
        series.push(Series::new(format!("implicit, {variant}"), sorted(pts)));
    }
    let pts = study(&results.rows, Study::Unconverged)
        .filter(|r| r.method == Method::Naive)
        .filter_map(|r| Some((r.reached_relative_residual?, r.grad_rel_err?)))
        .collect();
    series.push(Series::new("naive (fixed iterations)", sorted(pts)));
    series.push(Series::new(
        "error = residual",
        vec![(1e-12, 1e-12), (1.0, 1.0)],
    ));
    write_chart(
        out_dir,
        "stability_residual.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "forward relative residual ‖b − A p‖/‖b‖",
            y_label: "relative gradient error vs exact",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let floor_n = results.config.floor_n;
    let caption = format!("f32 floor: implicit f32 gradient error vs CG cap ({floor_n}²)");
    let pts: Vec<(f64, f64)> = study(&results.rows, Study::Floor)
        .filter_map(|r| {
            let e = if r.finite && r.error.is_none() {
                r.grad_rel_err?
            } else {
                f64::NAN
            };
            Some((r.max_iters? as f64, e))
        })
        .collect();
    let (lo, hi) = pts.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), p| {
        (lo.min(p.0), hi.max(p.0))
    });
    let series = vec![
        Series::new("implicit f32", pts),
        Series::new(
            "floor 1e-4",
            vec![(lo, F32_FLOOR_LIMIT), (hi, F32_FLOOR_LIMIT)],
        ),
    ];
    write_chart(
        out_dir,
        "stability_floor.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "fixed CG iterations (forward and adjoint)",
            y_label: "relative gradient error vs f64 exact",
            log_x: false,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = format!(
        "Gradient norm vs upwind advection steps ({} periodic cells; × = non-finite)",
        results.config.unroll_n
    );
    let mut series = Vec::new();
    for &cfl in &results.config.cfls {
        for p in [Precision::F64, Precision::F32] {
            let pts = results
                .unroll
                .iter()
                .filter(|u| u.cfl == cfl && u.precision == p)
                .map(|u| (u.steps as f64, u.grad_d0_norm.unwrap_or(f64::NAN)))
                .collect();
            series.push(Series::new(format!("‖∂L/∂d⁰‖ CFL {cfl} {p}"), pts));
        }
    }
    write_chart(
        out_dir,
        "stability_unroll.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "advection steps N",
            y_label: "‖∂L/∂d⁰‖₂",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = "Conditioning: CG iterations to convergence vs grid size".to_string();
    let mut series = Vec::new();
    for p in [Precision::F64, Precision::F32] {
        for op in [OperatorKind::Laplacian, OperatorKind::Neumann] {
            let pts = results
                .convergence
                .iter()
                .filter(|c| c.precision == p && c.operator == op)
                .filter_map(|c| Some((c.n as f64, c.iterations? as f64)))
                .collect();
            series.push(Series::new(format!("{} {p}", op.label()), sorted(pts)));
        }
    }
    write_chart(
        out_dir,
        "stability_conditioning.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "grid size n (n × n cells)",
            y_label: "CG iterations (f64 to 1e-10, f32 to 1e-5)",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );
    (charts, notes)
}

pub(super) fn sorted(mut pts: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts.dedup_by(|a, b| a.0 == b.0);
    pts
}

/// Writes `stability.json`: the whole [`StabilityResults`].
///
/// # Errors
/// [`CompareError::Json`] or [`CompareError::Io`].
pub fn write_stability_json(path: &Path, results: &StabilityResults) -> Result<()> {
    let text = serde_json::to_string_pretty(results)?;
    std::fs::write(path, text + "\n").map_err(|e| CompareError::io(path, e))
}

const STUDIES: [(Study, &str); 4] = [
    (Study::Iterations, "Precision and iteration counts"),
    (
        Study::Unconverged,
        "Forward solve stopped before convergence",
    ),
    (Study::Conditioning, "Conditioning"),
    (Study::Floor, "The f32 floor"),
];

/// Most rows a study's table in `stability.md` shows (the f32 floor study has
/// one run per iteration cap, hundreds of them).
const MAX_TABLE_ROWS: usize = 100;

/// At most about `max` of `rows`, evenly spaced, always keeping the row of the
/// largest gradient error and every row that failed or went non-finite.
fn table_sample(rows: &[ResultRow], max: usize) -> Vec<ResultRow> {
    if rows.len() <= max {
        return rows.to_vec();
    }
    let stride = rows.len().div_ceil(max);
    let worst = rows
        .iter()
        .enumerate()
        .filter_map(|(i, r)| r.grad_rel_err.filter(|e| e.is_finite()).map(|e| (i, e)))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i);
    rows.iter()
        .enumerate()
        .filter(|(i, r)| {
            i % stride == 0
                || *i + 1 == rows.len()
                || Some(*i) == worst
                || r.error.is_some()
                || !r.finite
        })
        .map(|(_, r)| r.clone())
        .collect()
}

/// `stability.md`: configuration, floors, findings, charts, and a table per
/// study (the sweep's [`crate::report::render_report`] for the CG studies).
pub fn render_stability_md(
    results: &StabilityResults,
    configuration: Vec<String>,
    charts: Vec<(String, String)>,
    notes: Vec<String>,
) -> String {
    use std::fmt::Write as _;
    let all: Vec<ResultRow> = STUDIES
        .iter()
        .flat_map(|&(s, _)| result_rows(results, s))
        .collect();
    let mut report_notes = results.findings.clone();
    report_notes.extend(notes);
    let head = crate::report::render_report(&crate::report::Report {
        title: "diffphys-compare stability: where gradient methods fail",
        configuration,
        rows: &[],
        floors: &results.floors,
        charts,
        notes: report_notes,
    });
    let mut out = head;
    let _ = writeln!(out, "\n## Studies\n\n{} CG runs in all.\n", all.len());
    for (key, title) in STUDIES {
        let rows = result_rows(results, key);
        let _ = writeln!(out, "### {title}\n");
        let shown = table_sample(&rows, MAX_TABLE_ROWS);
        if shown.len() < rows.len() {
            let _ = writeln!(
                out,
                "{} of {} runs: evenly spaced, plus the worst error and every failure; \
                 all of them are in `stability.json` and the chart.\n",
                shown.len(),
                rows.len()
            );
        }
        out.push_str(&crate::report::markdown_table(&shown));
        out.push('\n');
    }
    out.push_str("### Gradient with respect to the initial guess x0\n\n");
    out.push_str("| method | iterations | ‖∂L/∂x0‖ | exactly zero | FD of loss along d | <∂L/∂x0, d> | ‖∂L/∂b‖ | error |\n|---|---:|---:|---|---:|---:|---:|---|\n");
    for x in &results.initial_guess {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} | {} | {} |",
            x.method,
            x.iterations.map_or_else(
                || format!("rtol {:e}", x.rtol.unwrap_or(0.0)),
                |k| k.to_string()
            ),
            fmt(x.x0_grad_norm),
            x.x0_grad_exactly_zero
                .map_or("-", |z| if z { "yes" } else { "no" }),
            fmt(x.x0_finite_difference),
            fmt(x.x0_directional),
            fmt(x.b_grad_norm),
            x.error.as_deref().unwrap_or("")
        );
    }
    out.push_str("\n### Long unrolls: upwind advection\n\n");
    out.push_str(&unroll_table(&results.unroll, true));
    out
}

/// The unroll rows as a table (Markdown or plain text).
pub fn unroll_table(rows: &[UnrollRow], markdown: bool) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    if markdown {
        out.push_str("| CFL | prec | steps | loss | ‖∂L/∂d⁰‖ | ‖∂L/∂u‖ | finite | error |\n|---:|---|---:|---:|---:|---:|---|---|\n");
    } else {
        let _ = writeln!(
            out,
            "{:>5}  {:<4}  {:>6}  {:>10}  {:>10}  {:>10}  {:<6}  error",
            "CFL", "prec", "steps", "loss", "|dL/dd0|", "|dL/du|", "finite"
        );
    }
    for u in rows {
        let cells = [
            format!("{}", u.cfl),
            u.precision.to_string(),
            u.steps.to_string(),
            fmt(u.loss),
            fmt(u.grad_d0_norm),
            fmt(u.grad_u_norm),
            if u.finite { "yes" } else { "NO" }.to_string(),
            u.error.clone().unwrap_or_default(),
        ];
        if markdown {
            let _ = writeln!(
                out,
                "| {} |",
                cells.map(|c| c.replace('|', "\\|")).join(" | ")
            );
        } else {
            let _ = writeln!(
                out,
                "{:>5}  {:<4}  {:>6}  {:>10}  {:>10}  {:>10}  {:<6}  {}",
                cells[0], cells[1], cells[2], cells[3], cells[4], cells[5], cells[6], cells[7]
            );
        }
    }
    out
}

/// The key figures of a stability run as one JSON object: the sweep's counts
/// and floors ([`crate::report::key_figures_value`]) plus each failure mode's
/// headline figure.
pub fn stability_key_figures(
    results: &StabilityResults,
    out_dir: &Path,
    elapsed_s: f64,
) -> serde_json::Value {
    let rows: Vec<ResultRow> = results.rows.iter().map(|r| r.row.clone()).collect();
    let mut v = crate::report::key_figures_value(&rows, &results.floors, out_dir, elapsed_s);
    let first = |m: Method, p: Precision| first_failure(&results.rows, m, p).map(|(k, _)| k);
    let x0 = |m: Method| {
        results
            .initial_guess
            .iter()
            .filter(|x| x.method == m)
            .filter_map(|x| x.x0_grad_norm)
            .fold(None, |acc: Option<f64>, v| {
                Some(acc.map_or(v, |a| a.max(v)))
            })
    };
    let unroll_fail = |cfl: f64, p: Precision| {
        results
            .unroll
            .iter()
            .find(|u| u.cfl == cfl && u.precision == p && u.error.is_some())
            .map(|u| u.steps)
    };
    let unroll_last = |cfl: f64| {
        results
            .unroll
            .iter()
            .filter(|u| u.cfl == cfl && u.precision == Precision::F64)
            .filter_map(|u| u.grad_d0_norm)
            .next_back()
    };
    let ratios: Vec<f64> = results
        .rows
        .iter()
        .filter(|x| x.study == Study::Unconverged && x.variant.as_deref() == Some("adjoint tight"))
        .filter_map(|x| Some(x.row.grad_rel_err? / x.row.reached_relative_residual?))
        .collect();
    if let Some(o) = v.as_object_mut() {
        o.insert("mode".into(), "stability".into());
        o.insert("ok".into(), true.into());
        o.insert(
            "naive_first_non_finite_iters".into(),
            serde_json::json!({ "f32": first(Method::Naive, Precision::F32), "f64": first(Method::Naive, Precision::F64) }),
        );
        o.insert(
            "implicit_first_non_finite_iters".into(),
            serde_json::json!({ "f32": first(Method::Implicit, Precision::F32), "f64": first(Method::Implicit, Precision::F64) }),
        );
        o.insert(
            "x0_grad_norm_max".into(),
            serde_json::json!({ "implicit": x0(Method::Implicit), "naive": x0(Method::Naive) }),
        );
        o.insert(
            "unconverged_err_over_residual".into(),
            serde_json::json!({
                "min": ratios.iter().copied().reduce(f64::min),
                "max": ratios.iter().copied().reduce(f64::max),
            }),
        );
        let mut unroll = serde_json::Map::new();
        for &cfl in &results.config.cfls {
            unroll.insert(
                format!("cfl_{cfl}"),
                serde_json::json!({
                    "grad_d0_norm_last_f64": unroll_last(cfl),
                    "first_failing_steps_f64": unroll_fail(cfl, Precision::F64),
                    "first_failing_steps_f32": unroll_fail(cfl, Precision::F32),
                }),
            );
        }
        o.insert("unroll".into(), unroll.into());
    }
    v
}
