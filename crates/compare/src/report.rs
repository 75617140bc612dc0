//! Result rows and the files and tables made from them: `results.json`, the
//! printed table, `report.md`, the performance floors and the closing JSON line.

use std::fmt::Write as _;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::chart::format_value;
use crate::harness::MethodKind;
pub use crate::harness::Precision;
use crate::problem::OperatorKind;
use crate::{CompareError, Result};

/// What a row measured: a gradient method, the straightforward CG baseline, or
/// the scene's setup (a row for a scene that could not be built).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// CG unrolled on the tape.
    Naive,
    /// The Poisson op with its implicit adjoint.
    Implicit,
    /// The implicit gradient with multigrid-preconditioned CG for the forward
    /// and the adjoint solve.
    ImplicitMgpcg,
    /// The sparse Cholesky reference.
    Exact,
    /// The straightforward CG, forward only.
    BaselineCg,
    /// Building the scene, before any method ran.
    Setup,
}

impl Method {
    /// The methods a sweep can run (`--methods`), in the order a sweep runs them.
    pub const SELECTABLE: [Method; 5] = [
        Method::Exact,
        Method::BaselineCg,
        Method::Implicit,
        Method::ImplicitMgpcg,
        Method::Naive,
    ];

    /// The name in results: `naive`, `implicit`, `implicit_mgpcg`, `exact`,
    /// `baseline_cg`, `setup`.
    pub fn name(self) -> &'static str {
        match self {
            Method::Naive => "naive",
            Method::Implicit => "implicit",
            Method::ImplicitMgpcg => "implicit_mgpcg",
            Method::Exact => "exact",
            Method::BaselineCg => "baseline_cg",
            Method::Setup => "setup",
        }
    }

    /// Parses the name of one of [`Method::SELECTABLE`].
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] naming the valid methods.
    pub fn parse(s: &str) -> Result<Self> {
        Method::SELECTABLE
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                CompareError::invalid(format!(
                    "unknown method '{s}': expected one of {}",
                    Method::SELECTABLE.map(Method::name).join(", ")
                ))
            })
    }

    /// The gradient method of this kind, if it is one (not the forward-only
    /// baseline or the setup).
    pub fn gradient_kind(self) -> Option<MethodKind> {
        match self {
            Method::Naive => Some(MethodKind::Naive),
            Method::Implicit => Some(MethodKind::Implicit),
            Method::ImplicitMgpcg => Some(MethodKind::ImplicitMgpcg),
            Method::Exact => Some(MethodKind::Exact),
            Method::BaselineCg | Method::Setup => None,
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl From<MethodKind> for Method {
    fn from(kind: MethodKind) -> Self {
        match kind {
            MethodKind::Naive => Method::Naive,
            MethodKind::Implicit => Method::Implicit,
            MethodKind::ImplicitMgpcg => Method::ImplicitMgpcg,
            MethodKind::Exact => Method::Exact,
        }
    }
}

/// How a run ended. Not serialised (`results.json` keeps its fields): on reading,
/// it is recovered from the row's `error` ([`RunStatus::of_message`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum RunStatus {
    /// The run completed (its figures may still be non-finite).
    #[default]
    Ok,
    /// The run failed; `error` says why.
    Failed,
    /// The run was not attempted ([`CompareError::Skipped`]).
    Skipped,
    /// The run was refused before it allocated ([`CompareError::MemoryLimit`]).
    MemoryLimit,
}

impl RunStatus {
    /// The status of a run that ended in `e`.
    pub fn of_error(e: &CompareError) -> Self {
        match e {
            CompareError::Skipped(_) => RunStatus::Skipped,
            CompareError::MemoryLimit { .. } => RunStatus::MemoryLimit,
            _ => RunStatus::Failed,
        }
    }

    /// The status of a row read back from JSON, from its error message.
    pub fn of_message(error: Option<&str>) -> Self {
        match error {
            None => RunStatus::Ok,
            Some(e) if e.starts_with("skipped:") => RunStatus::Skipped,
            Some(e) if e.starts_with("memory limit:") => RunStatus::MemoryLimit,
            Some(_) => RunStatus::Failed,
        }
    }
}

/// Serialises an [`OperatorKind`] as its [`label`](OperatorKind::label)
/// (`laplacian`, `aniso100`, `neumann`) and parses it back.
pub mod operator_label {
    use serde::{Deserialize, Deserializer, Serializer};

    use crate::problem::OperatorKind;

    /// Writes the label.
    pub fn serialize<S: Serializer>(op: &OperatorKind, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&op.label())
    }

    /// Parses the label.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<OperatorKind, D::Error> {
        let label = String::deserialize(d)?;
        OperatorKind::parse(&label).map_err(serde::de::Error::custom)
    }
}

/// One measured run of one method on one scene. Serialised as a `results.json`
/// entry; `null` where a figure does not apply (no backward for a baseline, no
/// heap figure without the counting allocator, no error against exact when the
/// run failed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultRow {
    /// `naive`, `implicit`, `exact`, `baseline_cg`, `setup`.
    pub method: Method,
    /// `f32` or `f64`.
    pub precision: Precision,
    /// Cells per axis.
    pub n: usize,
    /// CG iterations of the forward solve (the fixed count, or what the tolerance
    /// needed); `null` for a direct solve.
    pub iterations: Option<usize>,
    /// The relative tolerance asked for; `null` for a fixed iteration count.
    pub rtol: Option<f64>,
    /// Seconds for the forward solve and the loss.
    pub forward_s: Option<f64>,
    /// Seconds for the gradient after the forward.
    pub backward_s: Option<f64>,
    /// Peak bytes held by the tape (0 without a tape).
    pub tape_bytes: usize,
    /// Peak heap bytes during the run above what was allocated before it
    /// (counting allocator); `null` if no counting allocator is installed.
    pub peak_heap_bytes: Option<usize>,
    /// `‖g − g_exact‖ / ‖g_exact‖` against the `f64` Cholesky gradient; `null`
    /// if the run failed or produced non-finite values.
    pub grad_rel_err: Option<f64>,
    /// True if the loss and every gradient entry stayed finite and no
    /// non-finite error was raised.
    pub finite: bool,
    /// The error, if the run failed.
    pub error: Option<String>,
    /// How the run ended (not serialised; see [`RunStatus`]).
    #[serde(skip)]
    pub status: RunStatus,
    /// A variant of the method shown beside it in tables (`naive (x0)`); not
    /// serialised.
    #[serde(skip)]
    pub variant: Option<String>,
    /// The operator (`laplacian`, `aniso100`): the conditioning axis.
    #[serde(with = "operator_label")]
    pub operator: OperatorKind,
    /// The iteration cap of a tolerance run, or the fixed count.
    pub max_iters: Option<usize>,
    /// CG iterations of the adjoint solve (implicit method).
    pub adjoint_iterations: Option<usize>,
    /// The relative residual `‖b − A p‖/‖b‖` the forward solution reached
    /// (recomputed in `f64`), to read beside the requested [`ResultRow::rtol`]: a
    /// tolerance below the rounding floor of the precision is not reached.
    #[serde(alias = "forward_residual")]
    pub reached_relative_residual: Option<f64>,
    /// The loss value.
    pub loss: Option<f64>,
    /// Relative error of the gradient's directional derivative against a central
    /// finite difference of the method's own loss (small grids only): small for a
    /// gradient that is the derivative of what the method computed.
    pub fd_rel_err: Option<f64>,
    /// Untimed warm-up runs before the timed ones
    /// ([`TimingPolicy`](crate::harness::TimingPolicy)).
    #[serde(default)]
    pub warmup_runs: usize,
    /// Forward + backward seconds of every timed run, in run order; the row's
    /// times are those of the run the policy's statistic picked. Empty for a
    /// run that was not timed.
    #[serde(default)]
    pub run_times_s: Vec<f64>,
}

impl ResultRow {
    /// A row with the identifying fields set and every figure empty.
    pub fn new(method: Method, precision: Precision, n: usize, operator: OperatorKind) -> Self {
        ResultRow {
            method,
            precision,
            n,
            iterations: None,
            rtol: None,
            forward_s: None,
            backward_s: None,
            tape_bytes: 0,
            peak_heap_bytes: None,
            grad_rel_err: None,
            finite: true,
            error: None,
            status: RunStatus::Ok,
            variant: None,
            operator,
            max_iters: None,
            adjoint_iterations: None,
            reached_relative_residual: None,
            loss: None,
            fd_rel_err: None,
            warmup_runs: 0,
            run_times_s: Vec::new(),
        }
    }

    /// `forward_s + backward_s` (the forward alone if there is no backward).
    pub fn total_s(&self) -> Option<f64> {
        self.forward_s.map(|f| f + self.backward_s.unwrap_or(0.0))
    }

    /// Records that the run ended in `e`: its message and its status.
    pub fn fail(&mut self, e: &CompareError) {
        self.error = Some(e.to_string());
        self.status = RunStatus::of_error(e);
    }

    /// True for a run that was attempted and failed (not skipped or refused).
    pub fn failed(&self) -> bool {
        self.status == RunStatus::Failed
    }

    /// `method precision`, the label of this row's curve in charts.
    pub fn series_label(&self) -> String {
        format!("{} {}", self.method, self.precision)
    }
}

/// True for a row that was not attempted ([`CompareError::Skipped`]).
pub fn is_skipped(row: &ResultRow) -> bool {
    row.status == RunStatus::Skipped
}

/// Writes `rows` as a pretty-printed JSON list.
///
/// # Errors
/// [`CompareError::Json`] or [`CompareError::Io`].
pub fn write_results_json(path: &Path, rows: &[ResultRow]) -> Result<()> {
    let text = serde_json::to_string_pretty(rows)?;
    std::fs::write(path, text + "\n").map_err(|e| CompareError::io(path, e))
}

/// Reads a `results.json` written by [`write_results_json`].
///
/// # Errors
/// [`CompareError::Io`] or [`CompareError::Json`].
pub fn read_results_json(path: &Path) -> Result<Vec<ResultRow>> {
    let text = std::fs::read_to_string(path).map_err(|e| CompareError::io(path, e))?;
    let mut rows: Vec<ResultRow> = serde_json::from_str(&text)?;
    for row in &mut rows {
        row.status = RunStatus::of_message(row.error.as_deref());
    }
    Ok(rows)
}

/// A byte count as `512 B`, `3.2 KiB`, `41.0 MiB`, `1.20 GiB`.
pub fn format_bytes(bytes: usize) -> String {
    let b = bytes as f64;
    const K: f64 = 1024.0;
    if b < K {
        format!("{bytes} B")
    } else if b < K * K {
        format!("{:.1} KiB", b / K)
    } else if b < K * K * K {
        format!("{:.1} MiB", b / (K * K))
    } else {
        format!("{:.2} GiB", b / (K * K * K))
    }
}

/// Seconds as `420 ns`, `3.25 µs`, `850 µs`, `12.3 ms`, `4.56 s`.
pub fn format_seconds(s: f64) -> String {
    if !s.is_finite() {
        s.to_string()
    } else if s < 1e-6 {
        format!("{:.0} ns", s * 1e9)
    } else if s < 1e-4 {
        format!("{:.2} µs", s * 1e6)
    } else if s < 1e-3 {
        format!("{:.0} µs", s * 1e6)
    } else if s < 1.0 {
        format!("{:.1} ms", s * 1e3)
    } else {
        format!("{s:.2} s")
    }
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

/// One performance floor of the project, measured as a ratio in this run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Floor {
    /// A short key (`heap_ratio`, …), used in the closing JSON line.
    pub key: String,
    /// What is compared, in words.
    pub description: String,
    /// The measured figure; `None` if the run did not include what it needs.
    pub measured: Option<f64>,
    /// The bound it must meet.
    pub limit: f64,
    /// True if `measured ≥ limit`, false if `measured ≤ limit` is required.
    pub at_least: bool,
    /// Why it was not measured, or a remark on the measurement.
    pub note: String,
}

impl Floor {
    /// Whether the floor holds; `None` if it was not measured.
    pub fn holds(&self) -> Option<bool> {
        self.measured.map(|m| {
            if self.at_least {
                m >= self.limit
            } else {
                m <= self.limit
            }
        })
    }

    fn verdict(&self) -> &'static str {
        match self.holds() {
            Some(true) => "holds",
            Some(false) => "FAILS",
            None => "not measured",
        }
    }
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
            f.verdict(),
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
            f.verdict(),
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
        let skipped = report.rows.iter().filter(|r| is_skipped(r)).count();
        let failed = report
            .rows
            .iter()
            .filter(|r| r.error.is_some() && !is_skipped(r))
            .count();
        let non_finite = report.rows.iter().filter(|r| !r.finite).count();
        let _ = writeln!(
            out,
            "## Results\n\n{} runs, {} failed, {} skipped, {} with non-finite values. Times are wall-clock \
             seconds; peak heap is measured by a counting allocator above the heap in use \
             before each run; gradient error is relative to the f64 sparse-Cholesky gradient. \
             `iters` counts forward CG iterations (`forward+adjoint` for the implicit method; in \
             parentheses, the count or cap a failed run was given).\n",
            report.rows.len(),
            failed,
            skipped,
            non_finite
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
/// measured value and verdict, the output folder and the elapsed time.
pub fn key_figures_line(
    rows: &[ResultRow],
    floors: &[Floor],
    out_dir: &Path,
    elapsed_s: f64,
) -> String {
    key_figures_value(rows, floors, out_dir, elapsed_s).to_string()
}

/// The object of [`key_figures_line`], for modes that add their own figures.
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
            }),
        );
    }
    serde_json::json!({
        "runs": rows.len(),
        "failed": rows.iter().filter(|r| r.error.is_some() && !is_skipped(r)).count(),
        "skipped": rows.iter().filter(|r| is_skipped(r)).count(),
        "non_finite": rows.iter().filter(|r| !r.finite).count(),
        "floors": floor_map,
        "floors_hold": floors.iter().all(|f| f.holds() != Some(false)),
        "out": out_dir.display().to_string(),
        "elapsed_s": (elapsed_s * 1000.0).round() / 1000.0,
    })
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
        let ok: Vec<&&ResultRow> = mine.iter().filter(|r| r.error.is_none()).collect();
        let max_f = |v: &mut dyn Iterator<Item = f64>| {
            v.fold(None, |a: Option<f64>, x| Some(a.map_or(x, |a| a.max(x))))
        };
        map.insert(
            m.name().to_string(),
            serde_json::json!({
                "runs": mine.len(),
                "ok": ok.len(),
                "failed": mine.iter().filter(|r| r.failed()).count(),
                "not_run": mine.iter().filter(|r| matches!(r.status, RunStatus::Skipped | RunStatus::MemoryLimit)).count(),
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
    fn bytes_and_seconds_format_readably() {
        assert_eq!(format_bytes(512), "512 B");
        assert_eq!(format_bytes(3 * 1024 * 1024), "3.0 MiB");
        assert_eq!(format_seconds(0.0123), "12.3 ms");
        assert_eq!(format_seconds(2.5), "2.50 s");
        assert_eq!(format_seconds(4.2e-7), "420 ns");
        assert_eq!(format_seconds(3.25e-6), "3.25 µs");
    }

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
    fn clipping_counts_characters_not_bytes() {
        assert_eq!(clip("αβγδ", 3), "αβ…");
        assert_eq!(clip("ab", 3), "ab");
    }
}
