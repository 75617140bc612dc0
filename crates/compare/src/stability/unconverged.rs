//! Study 3: forward solves stopped before convergence.

use ndarray::Array2;

use crate::harness::measure;
use crate::methods::implicit::{ImplicitSeparateAdjoint, ImplicitSolve};
use crate::methods::naive::NaiveUnrolled;
use crate::methods::Stop;
use crate::problem::{Problem, ProblemSpec};
use crate::progress::Progress;
use crate::Result;

use super::{stability_row, StabilityRow, Study, TOLERANCE_CAP};

/// Study 3: the implicit gradient with the forward solve stopped at each
/// tolerance (the adjoint tight, and the adjoint stopped alike), and the naive
/// gradient at fixed counts, on one `f64` scene.
///
/// # Errors
/// As [`iteration_study`](super::iteration_study).
pub fn unconverged_study(
    n: usize,
    rtols: &[f64],
    naive_counts: &[usize],
    exact: Option<&Array2<f64>>,
    bar: &dyn Progress,
) -> Result<Vec<StabilityRow>> {
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(n))?;
    let tight = Stop::Tolerance {
        rtol: 1e-12,
        max_iters: TOLERANCE_CAP,
    };
    let mut rows = Vec::new();
    for &rtol in rtols {
        let stop = Stop::Tolerance {
            rtol,
            max_iters: TOLERANCE_CAP,
        };
        bar.set_message(format!("unconverged: implicit rtol {rtol:e}"));
        let tight_method = ImplicitSeparateAdjoint { adjoint: tight };
        let (row, _) = measure(&tight_method, &problem, Some(stop), None, exact);
        let mut r = stability_row(Study::Unconverged, row);
        r.variant = Some("adjoint tight".into());
        rows.push(r);
        let (row, _) = measure(&ImplicitSolve, &problem, Some(stop), None, exact);
        let mut r = stability_row(Study::Unconverged, row);
        r.variant = Some("adjoint alike".into());
        rows.push(r);
        bar.inc(2);
    }
    for &k in naive_counts {
        bar.set_message(format!("unconverged: naive k={k}"));
        let (row, _) = measure(
            &NaiveUnrolled::default(),
            &problem,
            Some(Stop::Iterations(k)),
            None,
            exact,
        );
        rows.push(stability_row(Study::Unconverged, row));
        bar.inc(1);
    }
    Ok(rows)
}
