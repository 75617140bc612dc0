//! The performance floors, judged as ratios of rows measured in the same run.

use crate::problem::OperatorKind;
use crate::report::{Floor, Method, Precision, ResultRow};

/// The grid size and operator the performance floors are stated at.
pub const FLOOR_N: usize = 256;

/// The tolerance the floors are stated at.
pub const FLOOR_RTOL: f64 = 1e-8;

fn floor_row(rows: &[ResultRow], method: Method) -> Option<&ResultRow> {
    rows.iter().find(|r| {
        r.method == method
            && r.precision == Precision::F64
            && r.n == FLOOR_N
            && r.operator == OperatorKind::Laplacian
            && r.rtol == Some(FLOOR_RTOL)
    })
}

/// The performance floors, as ratios of rows measured in this run (at
/// 256×256, f64, the plain Laplacian, CG to 1e-8), with the CG per-iteration
/// ratio taken from `cg_speedup` (baseline time per iteration over the fused
/// solver's, if measured).
pub fn compute_floors(rows: &[ResultRow], cg_speedup: Option<(Option<f64>, String)>) -> Vec<Floor> {
    let naive = floor_row(rows, Method::Naive).filter(|r| r.error.is_none());
    let implicit = floor_row(rows, Method::Implicit).filter(|r| r.error.is_none());
    let at = format!("{FLOOR_N}², f64, laplacian, rtol {FLOOR_RTOL:e}");
    let why_not = |method: Method| -> String {
        match floor_row(rows, method) {
            None => format!("no {method} run at {at} in this sweep"),
            Some(r) => match &r.error {
                Some(e) => format!("{method} failed: {e}"),
                None => String::new(),
            },
        }
    };
    let err_note = |method: Method, row: Option<&ResultRow>| {
        let w = why_not(method);
        if w.is_empty() && row.and_then(|r| r.grad_rel_err).is_none() {
            "no exact reference gradient in this run, or a non-finite gradient".to_string()
        } else {
            w
        }
    };
    let both = naive.zip(implicit);
    let note_both = || {
        [why_not(Method::Naive), why_not(Method::Implicit)]
            .into_iter()
            .filter(|s| !s.is_empty())
            .collect::<Vec<_>>()
            .join("; ")
    };
    let ratio = |num: Option<f64>, den: Option<f64>| match (num, den) {
        (Some(a), Some(b)) if b > 0.0 => Some(a / b),
        _ => None,
    };
    let heap_ratio = both.and_then(|(n, i)| {
        ratio(
            i.peak_heap_bytes.map(|v| v as f64),
            n.peak_heap_bytes.map(|v| v as f64),
        )
    });
    let time_ratio = both.and_then(|(n, i)| ratio(i.total_s(), n.total_s()));
    let backward_ratio = implicit.and_then(|i| ratio(i.backward_s, i.forward_s));
    let worst_err = |r: Option<&ResultRow>| r.and_then(|r| r.grad_rel_err);
    let (speedup, speedup_note) = match cg_speedup {
        Some((s, note)) => (s, note),
        None => (
            None,
            "the fused CG of the implicit path is not timed yet".to_string(),
        ),
    };
    vec![
        Floor {
            key: "heap_ratio".into(),
            description: format!("implicit / naive peak heap ({at})"),
            measured: heap_ratio,
            limit: 0.01,
            at_least: false,
            note: note_both(),
        },
        Floor {
            key: "time_ratio".into(),
            description: format!("implicit / naive gradient time, forward + backward ({at})"),
            measured: time_ratio,
            limit: 0.2,
            at_least: false,
            note: note_both(),
        },
        Floor {
            key: "naive_grad_err".into(),
            description: format!("naive gradient error vs exact ({at})"),
            measured: worst_err(naive),
            limit: 1e-6,
            at_least: false,
            note: err_note(Method::Naive, naive),
        },
        Floor {
            key: "implicit_grad_err".into(),
            description: format!("implicit gradient error vs exact ({at})"),
            measured: worst_err(implicit),
            limit: 1e-6,
            at_least: false,
            note: err_note(Method::Implicit, implicit),
        },
        Floor {
            key: "implicit_backward_over_forward".into(),
            description: format!("implicit backward / forward time ({at})"),
            measured: backward_ratio,
            limit: 1.2,
            at_least: false,
            note: why_not(Method::Implicit),
        },
        Floor {
            key: "cg_iteration_speedup".into(),
            description: "straightforward / fused CG time per iteration".into(),
            measured: speedup,
            limit: 1.5,
            at_least: true,
            note: speedup_note,
        },
    ]
}
