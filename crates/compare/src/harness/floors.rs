//! The performance floors, judged as ratios of rows measured in the same run.

use crate::format::format_value;
use crate::model::{Floor, Method, Precision, ResultRow};
use crate::problem::OperatorKind;

/// The grid size and operator the performance floors are stated at.
pub const FLOOR_N: usize = 256;

/// The tolerance the floors are stated at.
pub const FLOOR_RTOL: f64 = 1e-8;

/// The grid size the MG-PCG against exact speed floor is judged at.
pub const MGPCG_FLOOR_N: usize = 1024;

/// The sizes the MG-PCG iteration floor covers: `64²` to `2048²`.
pub const MGPCG_FLOOR_SIZES: std::ops::RangeInclusive<usize> = 64..=2048;

/// The most MG-PCG iterations allowed to reach [`FLOOR_RTOL`] at any size.
pub const MGPCG_MAX_ITERATIONS: f64 = 15.0;

/// Completed f64, plain-Laplacian rows of `method` at `n` (any `n` if `None`)
/// solved to [`FLOOR_RTOL`] (exact rows: any, it has no tolerance).
fn f64_rows(rows: &[ResultRow], method: Method, n: Option<usize>) -> Vec<&ResultRow> {
    rows.iter()
        .filter(|r| {
            r.method == method
                && r.precision == Precision::F64
                && r.operator == OperatorKind::Laplacian
                && n.is_none_or(|n| r.n == n)
                && (method == Method::Exact || r.rtol == Some(FLOOR_RTOL))
                && r.error.is_none()
        })
        .collect()
}

/// The MG-PCG floors: its iteration count at [`FLOOR_RTOL`] over
/// [`MGPCG_FLOOR_SIZES`], its gradient error against exact there, and its
/// speed against the exact gradient at [`MGPCG_FLOOR_N`] (with the ratio at
/// every other size in the note).
fn mgpcg_floors(rows: &[ResultRow]) -> Vec<Floor> {
    let at = format!("f64, laplacian, rtol {FLOOR_RTOL:e}");
    let mg: Vec<&ResultRow> = f64_rows(rows, Method::ImplicitMgpcg, None)
        .into_iter()
        .filter(|r| MGPCG_FLOOR_SIZES.contains(&r.n))
        .collect();
    let sizes = |rs: &[&ResultRow]| {
        let mut ns: Vec<usize> = rs.iter().map(|r| r.n).collect();
        ns.sort_unstable();
        ns.dedup();
        ns.iter()
            .map(|n| format!("{n}²"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let none = || format!("no implicit_mgpcg run at {at} with n in 64..=2048 in this sweep");
    let iterations = mg
        .iter()
        .filter_map(|r| r.iterations.max(r.adjoint_iterations))
        .max()
        .map(|k| k as f64);
    let with_err: Vec<&ResultRow> = mg
        .iter()
        .copied()
        .filter(|r| r.grad_rel_err.is_some())
        .collect();
    let worst_err = with_err
        .iter()
        .filter_map(|r| r.grad_rel_err)
        .reduce(f64::max);
    let speedup = |n: usize| -> Option<f64> {
        let e = f64_rows(rows, Method::Exact, Some(n)).first()?.total_s()?;
        let m = f64_rows(rows, Method::ImplicitMgpcg, Some(n))
            .first()?
            .total_s()?;
        (m > 0.0).then(|| e / m)
    };
    let mut all_sizes: Vec<usize> = rows.iter().map(|r| r.n).collect();
    all_sizes.sort_unstable();
    all_sizes.dedup();
    let others: Vec<String> = all_sizes
        .iter()
        .filter_map(|&n| speedup(n).map(|s| format!("{n}²: {}", format_value(s))))
        .collect();
    vec![
        Floor {
            key: "mgpcg_max_iterations".into(),
            description: format!(
                "MG-PCG iterations (forward or adjoint, the larger) to reach the tolerance, \
                 every size 64²..2048² ({at})"
            ),
            measured: iterations,
            limit: MGPCG_MAX_ITERATIONS,
            at_least: false,
            note: if mg.is_empty() {
                none()
            } else {
                format!("sizes {}", sizes(&mg))
            },
        },
        Floor {
            key: "mgpcg_grad_err".into(),
            description: format!("MG-PCG gradient error vs exact, worst size ({at})"),
            measured: worst_err,
            limit: 1e-6,
            at_least: false,
            note: if mg.is_empty() {
                none()
            } else if with_err.is_empty() {
                "exact did not run at these sizes".into()
            } else {
                format!("sizes with an exact gradient: {}", sizes(&with_err))
            },
        },
        Floor {
            key: "mgpcg_speedup_vs_exact".into(),
            description: format!(
                "exact / MG-PCG gradient time, forward + backward ({MGPCG_FLOOR_N}², {at})"
            ),
            measured: speedup(MGPCG_FLOOR_N),
            limit: 3.0,
            at_least: true,
            note: if others.is_empty() {
                format!("needs exact and implicit_mgpcg at {MGPCG_FLOOR_N}² ({at})")
            } else {
                format!("every size: {}", others.join(", "))
            },
        },
    ]
}

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
/// solver's, if measured), then the MG-PCG floors (iterations over 64²..2048²,
/// gradient error, speed against exact at 1024²).
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
    let mut floors = vec![
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
    ];
    floors.extend(mgpcg_floors(rows));
    floors
}
