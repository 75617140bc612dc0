//! Studies 1 and 2: precision and fixed iteration counts past convergence, and
//! the floor of the implicit `f32` gradient.

use diffphys_tape::Real;
use ndarray::Array2;

use crate::harness::measure;
use crate::methods::implicit::ImplicitSolve;
use crate::methods::Stop;
use crate::model::{Floor, ResultRow};
use crate::problem::{Problem, ProblemSpec};
use crate::progress::Progress;
use crate::Result;

use super::{methods, stability_row, StabilityConfig, StabilityRow, Study, F32_FLOOR_LIMIT};

/// Study 1: both methods at fixed iteration counts, `f32` and `f64`, on one scene.
///
/// # Errors
/// [`CompareError::InvalidArgument`](crate::CompareError::InvalidArgument) for a bad grid size; method failures are rows.
pub fn iteration_study<T: Real>(
    spec: ProblemSpec,
    counts: &[usize],
    exact: Option<&Array2<f64>>,
    bar: &dyn Progress,
) -> Result<Vec<StabilityRow>> {
    let problem = Problem::<T>::new(spec)?;
    let mut rows = Vec::new();
    for &k in counts {
        for m in methods::<T>() {
            bar.set_message(format!("iterations: {} {} k={k}", m.name(), T::NAME));
            let (row, _) = measure(m.as_ref(), &problem, Some(Stop::Iterations(k)), None, exact);
            rows.push(stability_row(Study::Iterations, row));
            bar.inc(1);
        }
    }
    Ok(rows)
}

/// Study 2, the floor: the implicit gradient in `f32` at every `stride`-th
/// fixed iteration cap from `from` to `to`, against the `f64` exact gradient.
///
/// # Errors
/// As [`iteration_study`].
pub fn floor_study(
    n: usize,
    from: usize,
    to: usize,
    stride: usize,
    exact: Option<&Array2<f64>>,
    bar: &dyn Progress,
) -> Result<Vec<StabilityRow>> {
    let problem = Problem::<f32>::new(ProblemSpec::laplacian(n))?;
    let mut caps: Vec<usize> = (from..=to).step_by(stride.max(1)).collect();
    if caps.last() != Some(&to) {
        caps.push(to);
    }
    let mut rows = Vec::with_capacity(caps.len());
    for k in caps {
        bar.set_message(format!("f32 floor: implicit k={k}"));
        let (row, _) = measure(
            &ImplicitSolve,
            &problem,
            Some(Stop::Iterations(k)),
            None,
            exact,
        );
        rows.push(stability_row(Study::Floor, row));
        bar.inc(1);
    }
    Ok(rows)
}

/// The floor as measured: the worst error of the floor rows, failing if any is
/// non-finite or failed.
pub fn f32_floor(rows: &[StabilityRow], n: usize, from: usize, to: usize) -> Floor {
    let floor_rows: Vec<&ResultRow> = rows
        .iter()
        .filter(|r| r.study == Study::Floor)
        .map(|r| &r.row)
        .collect();
    let bad: Vec<String> = floor_rows
        .iter()
        .filter(|r| r.error.is_some() || r.grad_rel_err.is_none())
        .map(|r| {
            format!(
                "k={}: {}",
                r.max_iters.unwrap_or(0),
                r.error.as_deref().unwrap_or("non-finite gradient")
            )
        })
        .collect();
    let worst = floor_rows
        .iter()
        .filter_map(|r| r.grad_rel_err.map(|e| (e, r.max_iters.unwrap_or(0))))
        .max_by(|a, b| a.0.total_cmp(&b.0));
    let measured = match (bad.is_empty(), worst) {
        (true, Some((e, _))) => Some(e),
        // A failed or non-finite cap breaks the floor whatever the others did.
        (false, _) => Some(f64::INFINITY),
        (true, None) => None,
    };
    let mut note = format!("{} caps", floor_rows.len());
    if let Some((_, k)) = worst {
        note.push_str(&format!(", worst at k={k}"));
    }
    if !bad.is_empty() {
        note.push_str(&format!(
            "; {} caps failed or went non-finite, first: {}",
            bad.len(),
            bad[0]
        ));
    }
    Floor {
        key: "implicit_f32_floor".into(),
        description: format!(
            "worst implicit f32 gradient error vs f64 exact, {n}², every CG cap {from}..={to}"
        ),
        measured,
        limit: F32_FLOOR_LIMIT,
        at_least: false,
        note,
    }
}

/// The fixed iteration counts of study 1: the small counts, then each multiple
/// of the convergence count `k_conv`, sorted and deduplicated.
pub fn iteration_counts(config: &StabilityConfig, k_conv: usize) -> Vec<usize> {
    let mut counts: Vec<usize> = config
        .few_iterations
        .iter()
        .copied()
        .chain(
            config
                .convergence_multiples
                .iter()
                .map(|m| ((m * k_conv as f64).round() as usize).max(1)),
        )
        .collect();
    counts.sort_unstable();
    counts.dedup();
    counts
}
