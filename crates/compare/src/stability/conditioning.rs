//! Study 4: conditioning (growing sizes, anisotropy, the singular all-Neumann
//! system).

use diffphys_tape::Real;
use ndarray::Array2;

use crate::harness::{exact_reference, measure, ExactCache};
use crate::methods::implicit::ImplicitSolve;
use crate::methods::naive::NaiveUnrolled;
use crate::methods::{GradientMethod, Stop};
use crate::problem::{OperatorKind, Problem, ProblemSpec};
use crate::progress::Progress;
use crate::Result;

use super::{
    converged_rtol, convergence_iterations, convergence_row, null_space_fraction, stability_row,
    ConvergenceCount, StabilityConfig, StabilityRow, Study, TOLERANCE_CAP,
};

/// One conditioning scene in precision `T`: implicit and (up to
/// `naive_max_n`) naive to [`converged_rtol`](super::converged_rtol), then, on a singular system, the
/// naive method at five times its convergence count as well.
fn conditioning_scene<T: Real>(
    spec: ProblemSpec,
    naive_max_n: usize,
    exact: Option<&Array2<f64>>,
    bar: &dyn Progress,
    rows: &mut Vec<StabilityRow>,
) -> Result<()> {
    let problem = Problem::<T>::new(spec)?;
    let stop = Stop::Tolerance {
        rtol: converged_rtol::<T>(),
        max_iters: TOLERANCE_CAP,
    };
    let singular = spec.operator.null_space() != diffphys_ops::cg::NullSpace::None;
    let mut push = |m: &dyn GradientMethod<T>, stop: Stop| {
        let (row, out) = measure(m, &problem, Some(stop), None, exact);
        let mut r = stability_row(Study::Conditioning, row);
        if singular {
            r.null_space_fraction = out.and_then(|o| null_space_fraction(&o.gradient));
        }
        rows.push(r);
    };
    bar.set_message(format!(
        "conditioning: {} {} n={}",
        spec.operator.label(),
        T::NAME,
        spec.n
    ));
    push(&ImplicitSolve, stop);
    if spec.n <= naive_max_n {
        push(&NaiveUnrolled::default(), stop);
        if singular {
            if let Ok(k) = convergence_iterations(&problem) {
                push(&NaiveUnrolled::default(), Stop::Iterations(5 * k.max(1)));
            }
        }
    }
    bar.inc(1);
    Ok(())
}

/// Study 4: the plain Laplacian at growing sizes, anisotropic operators and the
/// singular all-Neumann system, both precisions.
///
/// # Errors
/// As [`iteration_study`](super::iteration_study).
pub fn conditioning_study(
    config: &StabilityConfig,
    cache: &mut ExactCache,
    bar: &dyn Progress,
) -> Result<(Vec<StabilityRow>, Vec<ConvergenceCount>)> {
    let mut specs: Vec<ProblemSpec> = config
        .laplacian_sizes
        .iter()
        .map(|&n| ProblemSpec::laplacian(n))
        .collect();
    specs.extend(config.anisotropic.iter().map(|&(n, ratio)| {
        ProblemSpec::laplacian(n).with_operator(OperatorKind::Anisotropic { ratio })
    }));
    specs.extend(
        config
            .neumann_sizes
            .iter()
            .map(|&n| ProblemSpec::laplacian(n).with_operator(OperatorKind::Neumann)),
    );
    let mut rows = Vec::new();
    let mut counts = Vec::new();
    for spec in specs {
        let exact = exact_reference(cache, spec);
        counts.push(convergence_row(&Problem::<f64>::new(spec)?));
        counts.push(convergence_row(&Problem::<f32>::new(spec)?));
        conditioning_scene::<f64>(spec, config.naive_max_n, exact.as_ref(), bar, &mut rows)?;
        conditioning_scene::<f32>(spec, config.naive_max_n, exact.as_ref(), bar, &mut rows)?;
    }
    Ok((rows, counts))
}
