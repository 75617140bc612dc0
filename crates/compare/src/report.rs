//! The files and tables made from result rows ([`crate::model`]):
//! `results.json`, the printed table, `report.md`, the floors and the closing
//! JSON line. It reads rows and floors only; it runs nothing.

use std::fmt::Write as _;
use std::path::Path;

use crate::format::{format_bytes, format_seconds, format_value};
use crate::model::{Floor, Method, ResultRow, RunStatus, Verdict};
use crate::{CompareError, Result};

/// Writes `rows` as a pretty-printed JSON list.
///
/// # Errors
/// [`CompareError::Json`] or [`CompareError::Io`].
pub fn write_results_json(path: &Path, rows: &[ResultRow]) -> Result<()> {
    let text = serde_json::to_string_pretty(rows)?;
    std::fs::write(path, text + "\n").map_err(|e| CompareError::io(path, e))
}

/// Reads a `results.json` written by [`write_results_json`]. Each row's
/// [`RunStatus`] is read as written; a file from before rows carried it reads
/// as `ok`, except that a row with an error is `failed` (never `ok`).
///
/// # Errors
/// [`CompareError::Io`] or [`CompareError::Json`].
pub fn read_results_json(path: &Path) -> Result<Vec<ResultRow>> {
    let text = std::fs::read_to_string(path).map_err(|e| CompareError::io(path, e))?;
    let mut rows: Vec<ResultRow> = serde_json::from_str(&text)?;
    for row in &mut rows {
        if row.error.is_some() && row.status == RunStatus::Ok {
            row.status = RunStatus::Failed;
        }
    }
    Ok(rows)
}

/// How the runs of a set ended, counted by [`RunStatus`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RunCounts {
    /// Rows.
    pub runs: usize,
    /// Runs that completed.
    pub ok: usize,
    /// Runs attempted that failed.
    pub failed: usize,
    /// Runs skipped (a naive tape over its limit).
    pub skipped: usize,
    /// Runs the memory guard refused.
    pub memory_limit: usize,
    /// Rows with a non-finite value (completed or not).
    pub non_finite: usize,
}

impl RunCounts {
    /// Counts `rows`.
    pub fn of(rows: &[ResultRow]) -> Self {
        let mut c = RunCounts {
            runs: rows.len(),
            ..RunCounts::default()
        };
        for r in rows {
            match r.status {
                RunStatus::Ok => c.ok += 1,
                RunStatus::Failed => c.failed += 1,
                RunStatus::Skipped => c.skipped += 1,
                RunStatus::MemoryLimit => c.memory_limit += 1,
            }
            c.non_finite += usize::from(!r.finite);
        }
        c
    }

    /// `20 runs: 0 completed, 4 failed, 0 skipped, 16 refused by the memory guard`.
    pub fn describe(&self) -> String {
        format!(
            "{} runs: {} completed, {} failed, {} skipped, {} refused by the memory guard",
            self.runs, self.ok, self.failed, self.skipped, self.memory_limit
        )
    }
}

/// Why the memory guard refused runs, from the refused rows' errors: the first
/// refusal's message, with how many more there were; `None` if it refused none.
pub fn memory_refusals(rows: &[ResultRow]) -> Option<String> {
    let mut refused = rows
        .iter()
        .filter(|r| r.status == RunStatus::MemoryLimit)
        .filter_map(|r| r.error.as_deref());
    let first = refused.next()?;
    Some(match refused.count() {
        0 => first.to_string(),
        more => format!("{first} (and {more} more runs refused)"),
    })
}

fn opt<T>(v: Option<T>, f: impl FnOnce(T) -> String) -> String {
    v.map_or_else(|| "-".to_string(), f)
}

const COLUMNS: [&str; 14] = [
    "method",
    "prec",
    "operator",
    "n",
    "iters",
    "rtol",
    "reached",
    "forward",
    "backward",
    "tape",
    "peak heap",
    "grad err",
    "finite",
    "error",
];

fn cells(row: &ResultRow) -> [String; 14] {
    [
        match &row.variant {
            Some(v) => format!("{} ({v})", row.method),
            None => row.method.to_string(),
        },
        row.precision.to_string(),
        row.operator.label(),
        row.n.to_string(),
        match (row.iterations, row.adjoint_iterations, row.max_iters) {
            (Some(f), Some(a), _) => format!("{f}+{a}"),
            (Some(f), None, _) => f.to_string(),
            // A failed run: the count or cap it was given.
            (None, _, Some(m)) => format!("({m})"),
            (None, _, None) => "-".to_string(),
        },
        opt(row.rtol, |v| format!("{v:.0e}")),
        opt(row.reached_relative_residual, |v| format!("{v:.1e}")),
        opt(row.forward_s, format_seconds),
        opt(row.backward_s, format_seconds),
        if row.tape_bytes > 0 {
            format_bytes(row.tape_bytes)
        } else {
            "-".to_string()
        },
        opt(row.peak_heap_bytes, format_bytes),
        opt(row.grad_rel_err, |v| format!("{v:.2e}")),
        if row.finite { "yes" } else { "NO" }.to_string(),
        row.error.clone().unwrap_or_default(),
    ]
}

/// Shortens an error message for a table cell.
fn clip(s: &str, max: usize) -> String {
    if s.chars().count() <= max {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(max.saturating_sub(1)).collect();
        t.push('…');
        t
    }
}

/// The rows as an aligned plain-text table for the terminal (errors clipped to
/// 60 characters; the full text is in `results.json`).
pub fn render_table(rows: &[ResultRow]) -> String {
    let body: Vec<[String; 14]> = rows
        .iter()
        .map(|r| {
            let mut c = cells(r);
            c[13] = clip(&c[13], 60);
            c
        })
        .collect();
    let mut widths = COLUMNS.map(|h| h.chars().count());
    for row in &body {
        for (w, c) in widths.iter_mut().zip(row) {
            *w = (*w).max(c.chars().count());
        }
    }
    let mut out = String::new();
    let line = |out: &mut String, cols: &[String]| {
        let mut s = String::new();
        for (k, (c, w)) in cols.iter().zip(widths).enumerate() {
            let pad = w - c.chars().count();
            // Text left-aligned, figures right-aligned.
            if !(3..12).contains(&k) {
                let _ = write!(s, "{c}{}", " ".repeat(pad));
            } else {
                let _ = write!(s, "{}{c}", " ".repeat(pad));
            }
            if k + 1 < cols.len() {
                s.push_str("  ");
            }
        }
        out.push_str(s.trim_end());
        out.push('\n');
    };
    line(&mut out, &COLUMNS.map(String::from));
    let rule: usize = widths.iter().sum::<usize>() + 2 * (widths.len() - 1);
    out.push_str(&"-".repeat(rule.min(160)));
    out.push('\n');
    for row in &body {
        line(&mut out, row);
    }
    out
}

/// The rows as a Markdown table (errors in full, `|` escaped).
pub fn markdown_table(rows: &[ResultRow]) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "| {} |", COLUMNS.join(" | "));
    let _ = writeln!(
        out,
        "|{}",
        COLUMNS
            .iter()
            .enumerate()
            .map(|(k, _)| if (3..12).contains(&k) {
                "---:|"
            } else {
                "---|"
            })
            .collect::<String>()
    );
    for row in rows {
        let c = cells(row).map(|s| s.replace('|', "\\|"));
        let _ = writeln!(out, "| {} |", c.join(" | "));
    }
    out
}

/// The floors as a Markdown table.
pub fn floors_markdown(floors: &[Floor]) -> String {
    let mut out =
        String::from("| floor | measured | required | verdict | note |\n|---|---:|---:|---|---|\n");
    for f in floors {
        let _ = writeln!(
            out,
            "| {} | {} | {} {} | {} | {} |",
            f.description,
            opt(f.measured, format_value),
            if f.at_least { "≥" } else { "≤" },
            format_value(f.limit),
            f.verdict().label(),
            f.note.replace('|', "\\|")
        );
    }
    out
}

/// The floors as plain text lines for the terminal.
pub fn floors_text(floors: &[Floor]) -> String {
    let mut out = String::new();
    for f in floors {
        let _ = writeln!(
            out,
            "{:<12} {:<70} {:>10} {} {:<6} {}",
            f.verdict().label(),
            f.description,
            opt(f.measured, format_value),
            if f.at_least { "≥" } else { "≤" },
            format_value(f.limit),
            f.note
        );
    }
    out
}

/// Everything `report.md` says.
#[derive(Debug, Clone)]
pub struct Report<'a> {
    /// The heading.
    pub title: &'a str,
    /// How the run was invoked and configured, one line per item.
    pub configuration: Vec<String>,
    /// The measured rows.
    pub rows: &'a [ResultRow],
    /// The floors measured in this run.
    pub floors: &'a [Floor],
    /// Chart files (relative to the report) with a caption each.
    pub charts: Vec<(String, String)>,
    /// Free-form remarks (failures explained, what was skipped).
    pub notes: Vec<String>,
}

/// Renders a [`Report`] as Markdown.
pub fn render_report(report: &Report<'_>) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# {}\n", report.title);
    if !report.configuration.is_empty() {
        out.push_str("## Configuration\n\n");
        for c in &report.configuration {
            let _ = writeln!(out, "- {c}");
        }
        out.push('\n');
    }
    if !report.floors.is_empty() {
        out.push_str("## Floors (measured in this run)\n\n");
        out.push_str(&floors_markdown(report.floors));
        out.push('\n');
    }
    if !report.charts.is_empty() {
        out.push_str("## Charts\n\n");
        for (file, caption) in &report.charts {
            let _ = writeln!(out, "### {caption}\n\n![{caption}]({file})\n");
        }
    }
    // A report of studies (the stability mode) has no sweep rows: no Results table.
    if !report.rows.is_empty() {
        let c = RunCounts::of(report.rows);
        let _ = writeln!(
            out,
            "## Results\n\n{} runs, {} failed, {} skipped, {} with non-finite values, {} refused by \
             the memory guard. Times are wall-clock \
             seconds; peak heap is measured by a counting allocator above the heap in use \
             before each run; gradient error is relative to the f64 sparse-Cholesky gradient. \
             `iters` counts forward CG iterations (`forward+adjoint` for the implicit method; in \
             parentheses, the count or cap a failed run was given).\n",
            c.runs, c.failed, c.skipped, c.non_finite, c.memory_limit
        );
        out.push_str(&markdown_table(report.rows));
    }
    if !report.notes.is_empty() {
        out.push_str("\n## Notes\n\n");
        for n in &report.notes {
            let _ = writeln!(out, "- {n}");
        }
    }
    out
}

/// Writes [`render_report`] to `path`.
///
/// # Errors
/// [`CompareError::Io`].
pub fn write_report_md(path: &Path, report: &Report<'_>) -> Result<()> {
    std::fs::write(path, render_report(report)).map_err(|e| CompareError::io(path, e))
}

/// The one-line JSON summary every run ends stdout with: counts, each floor's
/// measured value and verdict, the output folder and the elapsed time. See
/// [`key_figures_value`].
pub fn key_figures_line(
    rows: &[ResultRow],
    floors: &[Floor],
    out_dir: &Path,
    elapsed_s: f64,
) -> String {
    key_figures_value(rows, floors, out_dir, elapsed_s).to_string()
}

/// The object of [`key_figures_line`], for modes that add their own figures:
///
/// - `runs`, `failed` (attempted and failed), `skipped`, `refused` (by the
///   memory guard), `non_finite`: counts of rows by [`RunStatus`];
/// - `refused_reason`: why the memory guard refused runs ([`memory_refusals`]),
///   `null` if it refused none;
/// - `floors`: per floor key, `measured`, `limit`, `holds` (`null` if not
///   measured) and `verdict` (`holds`, `fails`, `not_measured`);
/// - `floors_hold`: `false` if a floor fails, `true` if every floor was
///   measured and holds, `null` otherwise: a floor without a measurement is
///   not measured, never held; `floors_not_measured` lists them;
/// - `out`, `elapsed_s`.
pub fn key_figures_value(
    rows: &[ResultRow],
    floors: &[Floor],
    out_dir: &Path,
    elapsed_s: f64,
) -> serde_json::Value {
    let mut floor_map = serde_json::Map::new();
    for f in floors {
        floor_map.insert(
            f.key.clone(),
            serde_json::json!({
                "measured": f.measured,
                "limit": f.limit,
                "holds": f.holds(),
                "verdict": f.verdict(),
            }),
        );
    }
    let c = RunCounts::of(rows);
    let not_measured: Vec<&str> = floors
        .iter()
        .filter(|f| f.verdict() == Verdict::NotMeasured)
        .map(|f| f.key.as_str())
        .collect();
    serde_json::json!({
        "runs": c.runs,
        "failed": c.failed,
        "skipped": c.skipped,
        "refused": c.memory_limit,
        "refused_reason": memory_refusals(rows),
        "non_finite": c.non_finite,
        "floors": floor_map,
        "floors_hold": floors_hold(floors),
        "floors_not_measured": not_measured,
        "out": out_dir.display().to_string(),
        "elapsed_s": (elapsed_s * 1000.0).round() / 1000.0,
    })
}

/// `Some(false)` if a floor fails, `Some(true)` if every floor was measured and
/// holds, `None` if none fails but one was not measured (or there are none).
pub fn floors_hold(floors: &[Floor]) -> Option<bool> {
    let verdicts: Vec<Verdict> = floors.iter().map(Floor::verdict).collect();
    if verdicts.contains(&Verdict::Fails) {
        Some(false)
    } else if verdicts.is_empty() || verdicts.contains(&Verdict::NotMeasured) {
        None
    } else {
        Some(true)
    }
}

/// Per method that has rows: how many runs it had, completed, failed and were
/// not attempted (skipped or refused for memory), the most forward iterations
/// of a completed run, the worst gradient error against exact and the longest
/// gradient time (forward + backward, seconds). For the closing JSON line.
pub fn method_summary(rows: &[ResultRow]) -> serde_json::Value {
    let mut map = serde_json::Map::new();
    for m in Method::SELECTABLE {
        let mine: Vec<&ResultRow> = rows.iter().filter(|r| r.method == m).collect();
        if mine.is_empty() {
            continue;
        }
        let ok: Vec<&&ResultRow> = mine.iter().filter(|r| r.ok()).collect();
        let max_f = |v: &mut dyn Iterator<Item = f64>| {
            v.fold(None, |a: Option<f64>, x| Some(a.map_or(x, |a| a.max(x))))
        };
        map.insert(
            m.name().to_string(),
            serde_json::json!({
                "runs": mine.len(),
                "ok": ok.len(),
                "failed": mine.iter().filter(|r| r.failed()).count(),
                "not_run": mine.iter().filter(|r| r.status.not_run()).count(),
                "max_iterations": ok.iter().filter_map(|r| r.iterations).max(),
                "worst_grad_rel_err": max_f(&mut ok.iter().filter_map(|r| r.grad_rel_err)),
                "max_gradient_s": max_f(&mut ok.iter().filter_map(|r| r.total_s())),
            }),
        );
    }
    serde_json::Value::Object(map)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floors_compare_in_the_right_direction() {
        let f = |m: f64, at_least: bool| Floor {
            key: "k".into(),
            description: "d".into(),
            measured: Some(m),
            limit: 1.5,
            at_least,
            note: String::new(),
        };
        assert_eq!(f(2.0, true).holds(), Some(true));
        assert_eq!(f(2.0, false).holds(), Some(false));
        assert_eq!(f(1.0, false).holds(), Some(true));
    }

    #[test]
    fn a_floor_without_a_measurement_is_never_held() {
        let f = |measured: Option<f64>| Floor {
            key: "k".into(),
            description: "d".into(),
            measured,
            limit: 1.0,
            at_least: false,
            note: String::new(),
        };
        assert_eq!(f(None).verdict(), Verdict::NotMeasured);
        assert_eq!(floors_hold(&[]), None);
        assert_eq!(floors_hold(&[f(None), f(None)]), None);
        assert_eq!(floors_hold(&[f(Some(0.5)), f(None)]), None);
        assert_eq!(
            floors_hold(&[f(Some(0.5)), f(Some(2.0)), f(None)]),
            Some(false)
        );
        assert_eq!(floors_hold(&[f(Some(0.5)), f(Some(1.0))]), Some(true));
        let v = key_figures_value(&[], &[f(None)], Path::new("o"), 0.0);
        assert_eq!(v["floors_hold"], serde_json::Value::Null);
        assert_eq!(v["floors"]["k"]["verdict"], "not_measured");
        assert_eq!(v["floors_not_measured"], serde_json::json!(["k"]));
    }

    #[test]
    fn runs_are_counted_by_status_and_refusals_give_their_reason() {
        use crate::model::Precision;
        use crate::problem::OperatorKind;
        let row = |status: RunStatus, error: Option<&str>| {
            let mut r = ResultRow::new(Method::Naive, Precision::F64, 8, OperatorKind::Laplacian);
            r.status = status;
            r.error = error.map(String::from);
            r
        };
        let rows = [
            row(RunStatus::Ok, None),
            row(RunStatus::Failed, Some("boom")),
            row(RunStatus::Skipped, Some("skipped: tape")),
            row(RunStatus::MemoryLimit, Some("memory limit: first")),
            row(RunStatus::MemoryLimit, Some("memory limit: second")),
        ];
        let c = RunCounts::of(&rows);
        assert_eq!(
            (c.runs, c.ok, c.failed, c.skipped, c.memory_limit),
            (5, 1, 1, 1, 2)
        );
        assert_eq!(
            memory_refusals(&rows).unwrap(),
            "memory limit: first (and 1 more runs refused)"
        );
        assert_eq!(memory_refusals(&rows[..3]), None);
        let v = key_figures_value(&rows, &[], Path::new("o"), 0.0);
        assert_eq!(
            (v["failed"].clone(), v["refused"].clone()),
            (1.into(), 2.into())
        );
    }

    #[test]
    fn clipping_counts_characters_not_bytes() {
        assert_eq!(clip("αβγδ", 3), "αβ…");
        assert_eq!(clip("ab", 3), "ab");
    }
}
