//! The findings of a stability run, in words, from its rows.

use crate::model::{Method, Precision, ResultRow};
use crate::problem::OperatorKind;

use super::{StabilityResults, StabilityRow, Study, UnrollRow};

pub(super) fn study(rows: &[StabilityRow], name: Study) -> impl Iterator<Item = &ResultRow> {
    rows.iter().filter(move |r| r.study == name).map(|r| &r.row)
}

/// The first fixed iteration count at which `method` in `precision` failed or
/// went non-finite in the iteration study, with its error.
pub fn first_failure(
    rows: &[StabilityRow],
    method: Method,
    precision: Precision,
) -> Option<(usize, String)> {
    study(rows, Study::Iterations)
        .filter(|r| r.method == method && r.precision == precision)
        .filter(|r| !r.finite || r.error.is_some())
        .filter_map(|r| Some((r.max_iters?, r.error.clone().unwrap_or_default())))
        .min_by_key(|(k, _)| *k)
}

fn worst_error_from(
    rows: &[StabilityRow],
    method: Method,
    precision: Precision,
    from: usize,
) -> Option<f64> {
    study(rows, Study::Iterations)
        .filter(|r| r.method == method && r.precision == precision)
        .filter(|r| r.max_iters.is_some_and(|k| k >= from))
        .map(|r| r.grad_rel_err.unwrap_or(f64::INFINITY))
        .reduce(f64::max)
}

pub(super) fn fmt(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".to_string(), |v| format!("{v:.2e}"))
}

/// One sentence per failure mode with the figures of this run.
pub fn findings(r: &StabilityResults) -> Vec<String> {
    let mut out = Vec::new();
    let n = r.config.iteration_n;
    let k_conv = r
        .convergence
        .iter()
        .find(|c| {
            c.n == n && c.precision == Precision::F64 && c.operator == OperatorKind::Laplacian
        })
        .and_then(|c| c.iterations)
        .unwrap_or(0);
    for p in [Precision::F32, Precision::F64] {
        let fail = first_failure(&r.rows, Method::Naive, p);
        out.push(format!(
            "iterations ({n}², {p}): CG converges in {k_conv} iterations (f64 to 1e-10); naive {}; \
             implicit worst error from {k_conv} iterations on: {} (all finite: {})",
            match &fail {
                Some((k, e)) => format!("first fails at {k} iterations: {e}"),
                None => format!(
                    "stays finite, worst error from {k_conv} iterations on {}",
                    fmt(worst_error_from(&r.rows, Method::Naive, p, k_conv))
                ),
            },
            fmt(worst_error_from(&r.rows, Method::Implicit, p, k_conv)),
            study(&r.rows, Study::Iterations)
                .filter(|x| x.method == Method::Implicit && x.precision == p)
                .all(|x| x.finite && x.error.is_none()),
        ));
    }
    for f in &r.floors {
        out.push(format!(
            "floor: {} = {} (≤ {}: {}; {})",
            f.description,
            fmt(f.measured),
            f.limit,
            match f.holds() {
                Some(true) => "holds",
                Some(false) => "FAILS",
                None => "not measured",
            },
            f.note
        ));
    }
    // Unconverged: ratio of gradient error to forward residual.
    let ratios: Vec<f64> = r
        .rows
        .iter()
        .filter(|x| x.study == Study::Unconverged && x.variant.as_deref() == Some("adjoint tight"))
        .filter_map(|x| Some(x.row.grad_rel_err? / x.row.reached_relative_residual?))
        .filter(|v| v.is_finite())
        .collect();
    if !ratios.is_empty() {
        let lo = ratios.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = ratios.iter().copied().fold(0.0, f64::max);
        out.push(format!(
            "unconverged forward ({}², f64, adjoint tight): implicit gradient error / forward \
             relative residual between {lo:.2} and {hi:.2} over forward tolerances {:?}",
            r.config.unconverged_n, r.config.forward_rtols
        ));
    }
    for (c, nsf) in r
        .rows
        .iter()
        .filter(|x| x.study == Study::Conditioning && x.row.operator == OperatorKind::Neumann)
        .map(|x| (&x.row, &x.null_space_fraction))
    {
        if c.method == Method::Naive {
            out.push(format!(
                "singular all-Neumann ({}², {}, naive, {}): {}",
                c.n,
                c.precision,
                match c.rtol {
                    Some(t) => format!("rtol {t:e}"),
                    None => format!("{} fixed iterations", c.max_iters.unwrap_or(0)),
                },
                match (&c.error, c.grad_rel_err) {
                    (Some(e), _) => format!("fails with a typed error: {e}"),
                    (None, Some(e)) => format!(
                        "finite, no drift along the kernel (share of the gradient along the \
                         constants {}); error {e:.2e} vs exact",
                        fmt(*nsf)
                    ),
                    (None, None) => "non-finite gradient".to_string(),
                }
            ));
        }
    }
    for x in &r.initial_guess {
        out.push(format!(
            "initial guess ({}, {}): ‖∂L/∂x0‖ = {} (exactly zero: {}), loss moves by {} per unit \
             of x0 along a fixed direction",
            x.method,
            x.iterations.map_or_else(
                || format!("rtol {:e}", x.rtol.unwrap_or(0.0)),
                |k| format!("{k} iterations")
            ),
            fmt(x.x0_grad_norm),
            x.x0_grad_exactly_zero
                .map_or("n/a", |z| if z { "yes" } else { "no" }),
            fmt(x.x0_finite_difference),
        ));
    }
    for &cfl in &r.config.cfls {
        for p in [Precision::F64, Precision::F32] {
            let rows: Vec<&UnrollRow> = r
                .unroll
                .iter()
                .filter(|u| u.cfl == cfl && u.precision == p)
                .collect();
            let last_finite = rows.iter().rev().find(|u| u.error.is_none());
            let first_fail = rows.iter().find(|u| u.error.is_some());
            out.push(format!(
                "unroll (CFL {cfl}, {p}): ‖∂L/∂d⁰‖ {} at N=1, {} at N={}{}",
                fmt(rows.first().and_then(|u| u.grad_d0_norm)),
                fmt(last_finite.and_then(|u| u.grad_d0_norm)),
                last_finite.map_or(0, |u| u.steps),
                first_fail.map_or_else(String::new, |u| format!(
                    "; N={} fails: {}",
                    u.steps,
                    u.error.as_deref().unwrap_or("")
                ))
            ));
        }
    }
    out
}
