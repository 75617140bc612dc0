//! One run of one method measured into one [`ResultRow`]: timings, tape and
//! heap bytes, the error against the exact gradient and against finite
//! differences.

use std::cell::Cell;
use std::time::Instant;

use diffphys_tape::pool::BufferPool;
use diffphys_tape::Real;
use ndarray::Array2;

use crate::alloc::{CountingAllocator, HeapWindow};
use crate::methods::baseline::{baseline_cg, StraightforwardLaplacian};
use crate::methods::{GradientMethod, RunOutcome, Stop};
use crate::model::{Method, Precision, ResultRow};
use crate::problem::Problem;

use super::policy::{Timed, TimingPolicy};
use super::relative_error;

/// Runs `method` once on `problem` and measures it into a row
/// ([`measure_with`] under [`TimingPolicy::single`]): for studies of accuracy,
/// where the time of one run is enough.
pub fn measure<T: Real>(
    method: &dyn GradientMethod<T>,
    problem: &Problem<T>,
    stop: Option<Stop>,
    heap: Option<&CountingAllocator>,
    exact: Option<&Array2<f64>>,
) -> (ResultRow, Option<RunOutcome<T>>) {
    measure_with(&TimingPolicy::single(), method, problem, stop, heap, exact)
}

/// Runs `method` on `problem` under `policy` (its warm-up runs, then its timed
/// runs, [`TimingPolicy::run`]) and measures the picked run into a row: its
/// timings and tape bytes, its peak heap (if `heap` is the installed global
/// allocator; each run in its own window), the error against `exact` (the `f64`
/// reference gradient, if known), every timed run's total seconds, and any
/// failure as the row's `error`. A failing method is a result, not an error.
pub fn measure_with<T: Real>(
    policy: &TimingPolicy,
    method: &dyn GradientMethod<T>,
    problem: &Problem<T>,
    stop: Option<Stop>,
    heap: Option<&CountingAllocator>,
    exact: Option<&Array2<f64>>,
) -> (ResultRow, Option<RunOutcome<T>>) {
    let mut row = ResultRow::new(
        method.method(),
        Precision::of::<T>(),
        problem.spec.n,
        problem.spec.operator,
    );
    row.rtol = stop.and_then(|s| s.rtol());
    row.max_iters = stop.map(|s| s.max_iters());
    row.warmup_runs = policy.warmup;
    // A direct method ignores the stopping rule.
    let stop = stop.unwrap_or(Stop::Iterations(0));
    let first_peak = Cell::new(None);
    // One buffer pool for the runs of this row, freed when the row is done:
    // the tapes of repeated runs reuse each other's buffers.
    let pool = BufferPool::with_limit_bytes(POOL_LIMIT_BYTES);
    let _current = pool.install();
    let result = policy.run(
        || {
            let window = cold_heap_window(heap, &first_peak, Some(&pool));
            let out = method.run(problem, stop)?;
            if let Some(w) = window {
                first_peak.set(Some(w.peak_above_baseline()));
            }
            Ok(out)
        },
        |out| out.forward_s + out.backward_s.unwrap_or(0.0),
    );
    match result {
        Ok(Timed {
            value: out, times, ..
        }) => {
            row.peak_heap_bytes = first_peak.get();
            row.run_times_s = times;
            row.forward_s = Some(out.forward_s);
            row.backward_s = out.backward_s;
            row.tape_bytes = out.tape_bytes;
            row.iterations = out.iterations;
            row.adjoint_iterations = out.adjoint_iterations;
            row.reached_relative_residual = out.forward_residual;
            row.loss = Some(out.loss);
            row.finite = out.loss.is_finite() && out.gradient.iter().all(|v| v.is_finite());
            row.grad_rel_err = exact.and_then(|g| relative_error(&out.gradient, g));
            (row, Some(out))
        }
        Err(e) => {
            row.finite = !e.is_non_finite();
            row.fail(&e);
            (row, None)
        }
    }
}

/// The most bytes the buffer pool of one row's runs keeps: an unrolled CG
/// tape at the harness's largest sizes records gigabytes, and a pool that
/// could hold only part of them would leave the later runs paying for fresh
/// memory the first run did not.
const POOL_LIMIT_BYTES: usize = 4 << 30;

/// The heap window of a policy's first run (warm-up or timed), `None` for the
/// others. The first run starts from an empty buffer pool (`pool`, if any, is
/// cleared),
/// so its peak counts every buffer the method needs; later runs reuse pooled
/// buffers (which is what makes them faster) and would report only what the
/// pool could not supply.
fn cold_heap_window<'h>(
    heap: Option<&'h CountingAllocator>,
    first_peak: &Cell<Option<usize>>,
    pool: Option<&BufferPool>,
) -> Option<HeapWindow<'h>> {
    let heap = heap?;
    if first_peak.get().is_some() {
        return None;
    }
    if let Some(pool) = pool {
        pool.clear();
    }
    Some(HeapWindow::start(heap))
}

/// The relative error of `gradient`'s directional derivative along a fixed
/// pseudo-random direction `d` (entries in `[−1, 1)`) against finite differences
/// of the method's own loss: the central difference `D(h) = (L(b + h d) −
/// L(b − h d)) / 2h` at `h = ε^(1/3)` and `h/2`, Richardson-extrapolated to
/// `(4 D(h/2) − D(h)) / 3` (error `O(h⁴)`: a truncated CG is a strongly curved
/// function of `b`). The method runs four more times with the same stopping rule.
/// The directional derivative uses the perturbation actually applied after
/// rounding to `T`.
///
/// Returns `None` in `f32`, where the loss resolves too few digits for any step
/// to balance truncation and rounding on a truncated solve, if a perturbed run
/// fails, or if the derivative is zero.
pub fn finite_difference_error<T: Real>(
    method: &dyn GradientMethod<T>,
    problem: &Problem<T>,
    stop: Stop,
    gradient: &Array2<T>,
) -> Option<f64> {
    if std::mem::size_of::<T>() < 8 {
        return None;
    }
    let shape = problem.b.shape().to_vec();
    let d = diffphys_tape::test_array::<T>(&shape, 0x5eed)
        .into_dimensionality::<ndarray::Ix2>()
        .ok()?;
    let shifted = |step: f64| {
        let mut p = problem.clone();
        let step = T::from_f64(step);
        p.b.zip_mut_with(&d, |b, &dv| *b += step * dv);
        p
    };
    // (finite difference, analytic directional derivative) at step h
    let central = |h: f64| -> Option<(f64, f64)> {
        let (plus, minus) = (shifted(h), shifted(-h));
        let l_plus = method.run(&plus, stop).ok()?.loss;
        let l_minus = method.run(&minus, stop).ok()?.loss;
        let analytic: f64 = gradient
            .iter()
            .zip(plus.b.iter().zip(&minus.b))
            .map(|(&g, (&bp, &bm))| g.as_f64() * (bp.as_f64() - bm.as_f64()) / (2.0 * h))
            .sum();
        Some(((l_plus - l_minus) / (2.0 * h), analytic))
    };
    let h = T::fd_step().as_f64();
    let (fd_h, an_h) = central(h)?;
    let (fd_half, an_half) = central(h / 2.0)?;
    let fd = (4.0 * fd_half - fd_h) / 3.0;
    let analytic = (4.0 * an_half - an_h) / 3.0;
    let scale = analytic.abs().max(fd.abs());
    (scale > 0.0 && fd.is_finite()).then(|| (fd - analytic).abs() / scale)
}

/// Times the straightforward CG ([`baseline_cg`]) on `problem`'s forward solve
/// once ([`measure_baseline_with`] under [`TimingPolicy::single`]).
pub fn measure_baseline<T: Real>(
    problem: &Problem<T>,
    stop: Stop,
    heap: Option<&CountingAllocator>,
) -> ResultRow {
    measure_baseline_with(&TimingPolicy::single(), problem, stop, heap)
}

/// Times the straightforward CG ([`baseline_cg`]) on `problem`'s forward solve
/// under `policy`: a forward-only row (`method = baseline_cg`, no backward, no
/// gradient) of the picked run.
pub fn measure_baseline_with<T: Real>(
    policy: &TimingPolicy,
    problem: &Problem<T>,
    stop: Stop,
    heap: Option<&CountingAllocator>,
) -> ResultRow {
    let mut row = ResultRow::new(
        Method::BaselineCg,
        Precision::of::<T>(),
        problem.spec.n,
        problem.spec.operator,
    );
    row.rtol = stop.rtol();
    row.max_iters = Some(stop.max_iters());
    row.warmup_runs = policy.warmup;
    let a = StraightforwardLaplacian::negative(&problem.grid);
    let b = problem.b.as_standard_layout();
    let b = b.as_slice().expect("standard layout");
    let first_peak = Cell::new(None);
    let result = policy.run(
        || {
            let window = cold_heap_window(heap, &first_peak, None);
            let start = Instant::now();
            let mut x = vec![T::zero(); b.len()];
            let info = baseline_cg(&a, b, &mut x, stop)?;
            let elapsed = start.elapsed().as_secs_f64();
            let finite = x.iter().all(|v| v.is_finite());
            if let Some(w) = window {
                first_peak.set(Some(w.peak_above_baseline()));
            }
            Ok((info, elapsed, finite))
        },
        |&(_, elapsed, _)| elapsed,
    );
    match result {
        Ok(Timed {
            value: (info, elapsed, finite),
            times,
            ..
        }) => {
            row.peak_heap_bytes = first_peak.get();
            row.run_times_s = times;
            row.forward_s = Some(elapsed);
            row.iterations = Some(info.iterations);
            row.reached_relative_residual = Some(info.relative_residual);
            row.finite = finite;
        }
        Err(e) => {
            row.finite = !e.is_non_finite();
            row.fail(&e);
        }
    }
    row
}
