//! Time per CG iteration: the straightforward baseline against the fused
//! solver of the implicit path, measured in the same run.

use std::time::Instant;

use diffphys_ops::OpsError;
use diffphys_tape::Real;
use serde::{Deserialize, Serialize};

use crate::format::format_seconds;
use crate::memory::{MemoryBudget, Storage};
use crate::methods::baseline::{baseline_cg, StraightforwardLaplacian};
use crate::methods::Stop;
use crate::model::Precision;
use crate::problem::{Problem, ProblemSpec};
use crate::{CompareError, Result};

use super::floors::FLOOR_N;
use super::sweep::SweepConfig;

/// Time per CG iteration of the straightforward baseline and of the solver of
/// the implicit path, on the same problem and iteration count in the same run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterationTiming {
    /// Cells per axis.
    pub n: usize,
    /// `f32` or `f64`.
    pub precision: Precision,
    /// Iterations each solver ran per timing.
    pub iterations: usize,
    /// Best seconds per iteration of [`baseline_cg`].
    pub baseline_s_per_iter: f64,
    /// Best seconds per iteration of the implicit path's solver.
    pub fused_s_per_iter: f64,
}

impl IterationTiming {
    /// `baseline / fused`: how many times faster an iteration of the fused solver is.
    pub fn speedup(&self) -> f64 {
        self.baseline_s_per_iter / self.fused_s_per_iter
    }
}

/// Times `iterations` CG iterations from `x = 0` on `problem.b` with the
/// baseline and with `fused` (which must run exactly that many iterations and
/// return the count it ran), after one untimed warm-up run of each, alternating
/// the two `repeats` times and keeping each one's best, so that both see the
/// same machine load.
///
/// # Errors
/// [`CompareError::InvalidArgument`] if `iterations` or `repeats` is zero or a
/// solver ran a different number of iterations; whatever either solver returns.
pub fn time_cg_iterations<T: Real>(
    problem: &Problem<T>,
    iterations: usize,
    repeats: usize,
    mut fused: impl FnMut(&Problem<T>, usize) -> Result<usize>,
) -> Result<IterationTiming> {
    if iterations == 0 || repeats == 0 {
        return Err(CompareError::invalid(
            "CG timing needs at least one iteration and one repeat",
        ));
    }
    let a = StraightforwardLaplacian::negative(&problem.grid);
    let b = problem.b.as_standard_layout();
    let b = b.as_slice().expect("standard layout");
    let (mut best_base, mut best_fused) = (f64::INFINITY, f64::INFINITY);
    // One untimed run of each first, as for every timed method of the sweep.
    let mut x = vec![T::zero(); b.len()];
    baseline_cg(&a, b, &mut x, Stop::Iterations(iterations))?;
    fused(problem, iterations)?;
    for _ in 0..repeats {
        let mut x = vec![T::zero(); b.len()];
        let start = Instant::now();
        let info = baseline_cg(&a, b, &mut x, Stop::Iterations(iterations))?;
        best_base = best_base.min(start.elapsed().as_secs_f64());
        let start = Instant::now();
        let ran = fused(problem, iterations)?;
        best_fused = best_fused.min(start.elapsed().as_secs_f64());
        if info.iterations != iterations || ran != iterations {
            return Err(CompareError::invalid(format!(
                "CG timing: asked for {iterations} iterations, baseline ran {}, fused ran {ran} \
                 (the residual vanished; time fewer iterations)",
                info.iterations
            )));
        }
    }
    Ok(IterationTiming {
        n: problem.spec.n,
        precision: Precision::of::<T>(),
        iterations,
        baseline_s_per_iter: best_base / iterations as f64,
        fused_s_per_iter: best_fused / iterations as f64,
    })
}

/// [`time_cg_iterations`] of the implicit path's solver
/// ([`diffphys_ops::cg::conjugate_gradient`], fixed iteration count) against the
/// baseline on the plain Laplacian of size `n` in precision `T`.
///
/// # Errors
/// As [`time_cg_iterations`], and a failed solve.
pub fn time_fused_cg<T: Real>(
    n: usize,
    iterations: usize,
    repeats: usize,
) -> Result<IterationTiming> {
    let problem = Problem::<T>::new(ProblemSpec::laplacian(n))?;
    let params = crate::methods::implicit::cg_params(Stop::Iterations(iterations));
    time_cg_iterations(&problem, iterations, repeats, |p, _| {
        let mut x = ndarray::ArrayD::<T>::zeros(ndarray::IxDyn(&[n, n]));
        let b = p.b.view().into_dyn();
        let info = diffphys_ops::cg::conjugate_gradient(&p.operator, b, x.view_mut(), &params)
            .map_err(OpsError::from)?;
        Ok(info.iterations)
    })
}

/// The per-iteration CG speedup of a sweep: timed at [`FLOOR_N`] if the sweep
/// includes it, else at its largest size, in `f64` if included; 200 iterations
/// (fewer on tiny grids, where the residual could vanish), one warm-up, best of 5. Returns the
/// ratio and a note saying where it was measured, or `None` with the failure.
pub fn cg_speedup(config: &SweepConfig) -> (Option<IterationTiming>, String) {
    let n = if config.sizes.contains(&FLOOR_N) {
        FLOOR_N
    } else {
        config.sizes.iter().copied().max().unwrap_or(FLOOR_N)
    };
    let iterations = 200.min(n * n / 2).max(1);
    let budget = MemoryBudget::new(config.memory_limit_mib);
    if let Err(e) = budget.check("CG timing", n, 8, Storage::Fields) {
        return (None, format!("CG timing not run: {e}"));
    }
    let result = if config.precisions.contains(&Precision::F64) {
        time_fused_cg::<f64>(n, iterations, 5)
    } else {
        time_fused_cg::<f32>(n, iterations, 5)
    };
    match result {
        Ok(t) => {
            let note = format!(
                "{}², {}, {} iterations, 1 warm-up then best of 5: baseline {} vs fused {} per iteration",
                t.n,
                t.precision,
                t.iterations,
                format_seconds(t.baseline_s_per_iter),
                format_seconds(t.fused_s_per_iter)
            );
            (Some(t), note)
        }
        Err(e) => (None, format!("CG timing failed: {e}")),
    }
}
