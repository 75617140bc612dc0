//! Measuring methods: one run into one [`ResultRow`], sweeps over sizes, stopping
//! rules, precisions and operators, the harness's charts and its floors.

use std::collections::HashMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use diffphys_ops::cg::CgError;
use diffphys_ops::OpsError;
use diffphys_tape::{Real, TapeError};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::alloc::{CountingAllocator, HeapWindow};
use crate::chart::{line_chart_svg, LineChart, Series};
use crate::methods::baseline::{baseline_cg, StraightforwardLaplacian};
use crate::methods::exact::ExactCholesky;
use crate::methods::implicit::ImplicitSolve;
use crate::methods::naive::NaiveUnrolled;
use crate::methods::{GradientMethod, RunOutcome, Stop};
use crate::problem::{LossKind, OperatorKind, Problem, ProblemSpec};
use crate::report::{Floor, ResultRow};
use crate::{CompareError, Result};

/// A scalar type of the study.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Precision {
    /// `f32`.
    F32,
    /// `f64`.
    F64,
}

impl Precision {
    /// `"f32"` or `"f64"`.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }

    /// Parses `f32` or `f64`.
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] for anything else.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "f32" => Ok(Precision::F32),
            "f64" => Ok(Precision::F64),
            other => Err(CompareError::invalid(format!(
                "unknown precision '{other}': expected f32 or f64"
            ))),
        }
    }
}

/// The gradient methods the harness compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum MethodKind {
    /// CG unrolled on the tape ([`NaiveUnrolled`]).
    Naive,
    /// The Poisson op with its implicit adjoint.
    Implicit,
    /// The sparse Cholesky reference.
    Exact,
}

impl MethodKind {
    /// The method's name in results.
    pub fn name(self) -> &'static str {
        match self {
            MethodKind::Naive => "naive",
            MethodKind::Implicit => "implicit",
            MethodKind::Exact => "exact",
        }
    }
}

/// The method of `kind` in precision `T`.
///
/// # Errors
/// None today; kept fallible so that a method whose operators are missing can
/// say so ([`CompareError::NotImplemented`]) instead of pretending to work.
pub fn method<T: Real>(kind: MethodKind) -> Result<Box<dyn GradientMethod<T>>> {
    match kind {
        MethodKind::Naive => Ok(Box::new(NaiveUnrolled::default())),
        MethodKind::Implicit => Ok(Box::new(ImplicitSolve)),
        MethodKind::Exact => Ok(Box::new(ExactCholesky)),
    }
}

/// True if `e` reports a NaN or infinity (as opposed to a bad argument or a
/// solver that ran out of iterations).
pub fn is_non_finite(e: &CompareError) -> bool {
    fn tape(e: &TapeError) -> bool {
        match e {
            TapeError::NonFinite { .. } => true,
            TapeError::Op { source, .. } => {
                source.downcast_ref::<OpsError>().is_some_and(ops)
                    || source.downcast_ref::<CgError>().is_some_and(cg)
            }
            _ => false,
        }
    }
    fn cg(e: &CgError) -> bool {
        matches!(e, CgError::NonFinite { .. })
    }
    fn ops(e: &OpsError) -> bool {
        match e {
            OpsError::NonFinite { .. } => true,
            OpsError::Tape(t) => tape(t),
            OpsError::Cg(c) => cg(c),
            _ => false,
        }
    }
    match e {
        CompareError::NonFinite { .. } => true,
        CompareError::Tape(t) | CompareError::NaiveIteration { source: t, .. } => tape(t),
        CompareError::Ops(o) | CompareError::UnrollStep { source: o, .. } => ops(o),
        _ => false,
    }
}

/// `‖g − g*‖ / ‖g*‖` in `f64` (`‖g − g*‖` if `g* = 0`); `None` if `g` holds a
/// non-finite value or the shapes differ.
pub fn relative_error<T: Real>(g: &Array2<T>, exact: &Array2<f64>) -> Option<f64> {
    if g.dim() != exact.dim() || g.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let (mut num, mut den) = (0.0, 0.0);
    for (&a, &b) in g.iter().zip(exact) {
        num += (a.as_f64() - b).powi(2);
        den += b * b;
    }
    Some(if den > 0.0 {
        (num / den).sqrt()
    } else {
        num.sqrt()
    })
}

/// Runs `method` once on `problem` and measures it into a row: its timings and
/// tape bytes, the peak heap (if `heap` is the installed global allocator), the
/// error against `exact` (the `f64` reference gradient, if known), and any
/// failure as the row's `error`. A failing method is a result, not an error.
pub fn measure<T: Real>(
    method: &dyn GradientMethod<T>,
    problem: &Problem<T>,
    stop: Option<Stop>,
    heap: Option<&CountingAllocator>,
    exact: Option<&Array2<f64>>,
) -> (ResultRow, Option<RunOutcome<T>>) {
    let mut row = ResultRow::new(
        method.name(),
        T::NAME,
        problem.spec.n,
        &problem.spec.operator.label(),
    );
    row.rtol = stop.and_then(|s| s.rtol());
    row.max_iters = stop.map(|s| s.max_iters());
    let window = heap.map(HeapWindow::start);
    // A direct method ignores the stopping rule.
    let result = method.run(problem, stop.unwrap_or(Stop::Iterations(0)));
    row.peak_heap_bytes = window.map(|w| w.peak_above_baseline());
    match result {
        Ok(out) => {
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
            row.finite = !is_non_finite(&e);
            row.error = Some(e.to_string());
            (row, None)
        }
    }
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

/// Times the straightforward CG ([`baseline_cg`]) on `problem`'s forward solve:
/// a forward-only row (`method = baseline_cg`, no backward, no gradient).
pub fn measure_baseline<T: Real>(
    problem: &Problem<T>,
    stop: Stop,
    heap: Option<&CountingAllocator>,
) -> ResultRow {
    let mut row = ResultRow::new(
        "baseline_cg",
        T::NAME,
        problem.spec.n,
        &problem.spec.operator.label(),
    );
    row.rtol = stop.rtol();
    row.max_iters = Some(stop.max_iters());
    let a = StraightforwardLaplacian::negative(&problem.grid);
    let b = problem.b.as_standard_layout();
    let b = b.as_slice().expect("standard layout");
    let window = heap.map(HeapWindow::start);
    let start = Instant::now();
    let mut x = vec![T::zero(); b.len()];
    let result = baseline_cg(&a, b, &mut x, stop);
    let elapsed = start.elapsed().as_secs_f64();
    row.peak_heap_bytes = window.map(|w| w.peak_above_baseline());
    match result {
        Ok(info) => {
            row.forward_s = Some(elapsed);
            row.iterations = Some(info.iterations);
            row.reached_relative_residual = Some(info.relative_residual);
            row.finite = x.iter().all(|v| v.is_finite());
        }
        Err(e) => {
            row.finite = !is_non_finite(&e);
            row.error = Some(e.to_string());
        }
    }
    row
}

/// Time per CG iteration of the straightforward baseline and of the solver of
/// the implicit path, on the same problem and iteration count in the same run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterationTiming {
    /// Cells per axis.
    pub n: usize,
    /// `f32` or `f64`.
    pub precision: String,
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
/// return the count it ran), alternating the two `repeats` times and keeping each
/// one's best, so that both see the same machine load.
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
        precision: T::NAME.to_string(),
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
/// (fewer on tiny grids, where the residual could vanish), best of 5. Returns the
/// ratio and a note saying where it was measured, or `None` with the failure.
pub fn cg_speedup(config: &SweepConfig) -> (Option<IterationTiming>, String) {
    let n = if config.sizes.contains(&FLOOR_N) {
        FLOOR_N
    } else {
        config.sizes.iter().copied().max().unwrap_or(FLOOR_N)
    };
    let iterations = 200.min(n * n / 2).max(1);
    let result = if config.precisions.contains(&Precision::F64) {
        time_fused_cg::<f64>(n, iterations, 5)
    } else {
        time_fused_cg::<f32>(n, iterations, 5)
    };
    match result {
        Ok(t) => {
            let note = format!(
                "{}², {}, {} iterations, best of 5: baseline {} vs fused {} per iteration",
                t.n,
                t.precision,
                t.iterations,
                crate::report::format_seconds(t.baseline_s_per_iter),
                crate::report::format_seconds(t.fused_s_per_iter)
            );
            (Some(t), note)
        }
        Err(e) => (None, format!("CG timing failed: {e}")),
    }
}

/// What a sweep runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepConfig {
    /// Grid sizes `n` (the grid is `n × n`).
    pub sizes: Vec<usize>,
    /// Fixed CG iteration counts.
    pub iters: Vec<usize>,
    /// Relative tolerances (each run to convergence or `max_iters`).
    pub rtols: Vec<f64>,
    /// The iteration cap of tolerance runs.
    pub max_iters: usize,
    /// Scalar types.
    pub precisions: Vec<Precision>,
    /// Operators (the conditioning axis).
    pub operators: Vec<OperatorKind>,
    /// The loss.
    pub loss: LossKind,
    /// Grids up to this size also get a finite-difference check of each gradient
    /// (two more runs of the method), in [`ResultRow::fd_rel_err`].
    pub fd_max_n: usize,
    /// Naive runs whose tape is estimated above this many bytes are skipped (and
    /// reported as skipped): unrolling thousands of iterations of a large grid
    /// does not fit in memory, which is the point, but should not crash the run.
    pub naive_tape_limit_bytes: usize,
}

impl SweepConfig {
    /// The default run: the README's main job, under two minutes on two cores.
    pub fn default_run() -> Self {
        SweepConfig {
            sizes: vec![32, 64, 128, 256],
            iters: vec![10, 30, 100, 300],
            rtols: vec![1e-4, 1e-6, 1e-8],
            max_iters: 20_000,
            precisions: vec![Precision::F32, Precision::F64],
            operators: vec![
                OperatorKind::Laplacian,
                OperatorKind::Anisotropic { ratio: 100.0 },
            ],
            loss: LossKind::Tracking,
            fd_max_n: 32,
            naive_tape_limit_bytes: 3 << 30,
        }
    }

    /// A tiny run for CI: seconds, every code path, no floors.
    pub fn quick() -> Self {
        SweepConfig {
            sizes: vec![8, 16],
            iters: vec![5, 20],
            rtols: vec![1e-6],
            max_iters: 2_000,
            precisions: vec![Precision::F32, Precision::F64],
            operators: vec![OperatorKind::Laplacian],
            loss: LossKind::Tracking,
            fd_max_n: 16,
            naive_tape_limit_bytes: 256 << 20,
        }
    }

    /// The stopping rules of the sweep: fixed counts, then tolerances.
    pub fn stops(&self) -> Vec<Stop> {
        self.iters
            .iter()
            .map(|&k| Stop::Iterations(k))
            .chain(self.rtols.iter().map(|&rtol| Stop::Tolerance {
                rtol,
                max_iters: self.max_iters,
            }))
            .collect()
    }

    /// Checks the configuration.
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] for an empty list, a size below 2, a
    /// tolerance not in `(0, 1)`, or a zero iteration count or cap.
    pub fn validate(&self) -> Result<()> {
        let fail = |m: String| Err(CompareError::invalid(m));
        if self.sizes.is_empty() || self.precisions.is_empty() || self.operators.is_empty() {
            return fail("sizes, precisions and operators must each list at least one".into());
        }
        if self.iters.is_empty() && self.rtols.is_empty() {
            return fail(
                "give at least one iteration count (--iters) or tolerance (--rtol)".into(),
            );
        }
        if let Some(n) = self.sizes.iter().find(|&&n| n < 2) {
            return fail(format!("grid size {n} is too small (need ≥ 2)"));
        }
        if let Some(r) = self.rtols.iter().find(|r| !(**r > 0.0 && **r < 1.0)) {
            return fail(format!("tolerance {r} is not in (0, 1)"));
        }
        if self.iters.contains(&0) || self.max_iters == 0 {
            return fail("iteration counts and the cap must be positive".into());
        }
        Ok(())
    }

    /// How many rows a sweep produces (for the progress bar).
    pub fn run_count(&self) -> usize {
        let per_scene = 1 + 1 + 2 * self.stops().len(); // exact, baseline, naive + implicit per stop
        per_scene * self.sizes.len() * self.precisions.len() * self.operators.len()
    }
}

/// Bytes the naive tape holds per CG iteration: seven arrays of the grid.
pub fn naive_bytes_per_iteration<T: Real>(n: usize) -> usize {
    7 * n * n * std::mem::size_of::<T>()
}

/// A progress bar on stderr, hidden when stderr is not a terminal (CI, pipes).
pub fn progress_bar(len: usize, what: &str) -> ProgressBar {
    let target = if std::io::stderr().is_terminal() {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    let bar = ProgressBar::with_draw_target(Some(len as u64), target);
    if let Ok(style) =
        ProgressStyle::with_template("{prefix} [{elapsed_precise}] {bar:32} {pos}/{len} {msg}")
    {
        bar.set_style(style);
    }
    bar.set_prefix(what.to_string());
    bar
}

/// The `f64` exact gradient of a scene, computed once per scene.
pub(crate) type ExactCache = HashMap<(usize, String), Option<Array2<f64>>>;

pub(crate) fn exact_reference(cache: &mut ExactCache, spec: ProblemSpec) -> Option<Array2<f64>> {
    cache
        .entry((spec.n, spec.operator.label()))
        .or_insert_with(|| {
            let problem = Problem::<f64>::new(spec).ok()?;
            let exact = method::<f64>(MethodKind::Exact).ok()?;
            exact
                .run(&problem, Stop::Iterations(0))
                .ok()
                .map(|o| o.gradient)
        })
        .clone()
}

fn sweep_scene<T: Real>(
    config: &SweepConfig,
    spec: ProblemSpec,
    exact: Option<&Array2<f64>>,
    heap: Option<&CountingAllocator>,
    bar: &ProgressBar,
    rows: &mut Vec<ResultRow>,
) {
    let label = format!("{} {} n={}", spec.operator.label(), T::NAME, spec.n);
    let problem = match Problem::<T>::new(spec) {
        Ok(p) => p,
        Err(e) => {
            let mut row = ResultRow::new("setup", T::NAME, spec.n, &spec.operator.label());
            row.error = Some(e.to_string());
            rows.push(row);
            bar.inc(config.run_count() as u64);
            return;
        }
    };
    let failed_row = |kind: MethodKind, stop: Option<Stop>, e: CompareError| {
        let mut row = ResultRow::new(kind.name(), T::NAME, spec.n, &spec.operator.label());
        row.rtol = stop.and_then(|s| s.rtol());
        row.max_iters = stop.map(|s| s.max_iters());
        row.error = Some(e.to_string());
        row
    };

    bar.set_message(format!("{label} exact"));
    let with_fd = spec.n <= config.fd_max_n;
    let measure_fd = |m: &dyn GradientMethod<T>, stop: Option<Stop>| {
        let (mut row, out) = measure(m, &problem, stop, heap, exact);
        if let (true, Some(out)) = (with_fd, out) {
            let stop = stop.unwrap_or(Stop::Iterations(0));
            row.fd_rel_err = finite_difference_error(m, &problem, stop, &out.gradient);
        }
        row
    };
    rows.push(match method::<T>(MethodKind::Exact) {
        Ok(m) => measure_fd(m.as_ref(), None),
        Err(e) => failed_row(MethodKind::Exact, None, e),
    });
    bar.inc(1);

    let tightest = config.rtols.iter().copied().fold(f64::INFINITY, f64::min);
    let baseline_stop = if tightest.is_finite() {
        Stop::Tolerance {
            rtol: tightest,
            max_iters: config.max_iters,
        }
    } else {
        Stop::Iterations(config.iters.iter().copied().max().unwrap_or(1))
    };
    bar.set_message(format!("{label} baseline CG"));
    let baseline = measure_baseline(&problem, baseline_stop, heap);
    // Iterations the tightest tolerance needs, to size naive tapes if the
    // implicit run cannot tell.
    let baseline_iters = baseline.iterations.filter(|_| baseline.error.is_none());
    rows.push(baseline);
    bar.inc(1);

    for stop in config.stops() {
        // The implicit run first: its iteration count sizes the naive tape.
        bar.set_message(format!("{label} implicit {stop:?}"));
        let implicit_iters = match method::<T>(MethodKind::Implicit) {
            Ok(m) => {
                let row = measure_fd(m.as_ref(), Some(stop));
                let it = row.iterations;
                rows.push(row);
                it
            }
            Err(e) => {
                rows.push(failed_row(MethodKind::Implicit, Some(stop), e));
                None
            }
        };
        bar.inc(1);

        bar.set_message(format!("{label} naive {stop:?}"));
        let expected_iters = match stop {
            Stop::Iterations(k) => k,
            Stop::Tolerance { max_iters, .. } => implicit_iters
                .or(baseline_iters)
                .unwrap_or(max_iters)
                .min(max_iters),
        };
        let estimate = expected_iters.saturating_mul(naive_bytes_per_iteration::<T>(spec.n));
        if estimate > config.naive_tape_limit_bytes {
            rows.push(failed_row(
                MethodKind::Naive,
                Some(stop),
                CompareError::Skipped(format!(
                    "~{expected_iters} unrolled iterations would need a tape of about {} (limit {})",
                    crate::report::format_bytes(estimate),
                    crate::report::format_bytes(config.naive_tape_limit_bytes)
                )),
            ));
        } else {
            rows.push(measure_fd(&NaiveUnrolled::default(), Some(stop)));
        }
        bar.inc(1);
    }
}

/// Runs every scene of `config` with every method and stopping rule, returning
/// one row per run (failures included, as rows with an `error`).
///
/// # Errors
/// [`CompareError::InvalidArgument`] if the configuration is invalid (see
/// [`SweepConfig::validate`]); method failures are rows, not errors.
pub fn run_sweep(config: &SweepConfig, heap: Option<&CountingAllocator>) -> Result<Vec<ResultRow>> {
    config.validate()?;
    let bar = progress_bar(config.run_count(), "sweep");
    let mut rows = Vec::with_capacity(config.run_count());
    let mut cache = ExactCache::new();
    for &operator in &config.operators {
        for &n in &config.sizes {
            let spec = ProblemSpec {
                n,
                operator,
                loss: config.loss,
            };
            bar.set_message(format!("{} n={n} exact reference", operator.label()));
            let exact = exact_reference(&mut cache, spec);
            for &precision in &config.precisions {
                match precision {
                    Precision::F32 => {
                        sweep_scene::<f32>(config, spec, exact.as_ref(), heap, &bar, &mut rows)
                    }
                    Precision::F64 => {
                        sweep_scene::<f64>(config, spec, exact.as_ref(), heap, &bar, &mut rows)
                    }
                }
            }
        }
    }
    bar.finish_and_clear();
    Ok(rows)
}

/// The grid size and operator the floors are stated at.
pub const FLOOR_N: usize = 256;
/// The tolerance the floors are stated at.
pub const FLOOR_RTOL: f64 = 1e-8;

fn floor_row<'a>(rows: &'a [ResultRow], method: &str) -> Option<&'a ResultRow> {
    rows.iter().find(|r| {
        r.method == method
            && r.precision == "f64"
            && r.n == FLOOR_N
            && r.operator == OperatorKind::Laplacian.label()
            && r.rtol == Some(FLOOR_RTOL)
    })
}

/// The performance floors, as ratios of rows measured in this run (at
/// 256×256, f64, the plain Laplacian, CG to 1e-8), with the CG per-iteration
/// ratio taken from `cg_speedup` (baseline time per iteration over the fused
/// solver's, if measured).
pub fn compute_floors(rows: &[ResultRow], cg_speedup: Option<(Option<f64>, String)>) -> Vec<Floor> {
    let naive = floor_row(rows, "naive").filter(|r| r.error.is_none());
    let implicit = floor_row(rows, "implicit").filter(|r| r.error.is_none());
    let at = format!("{FLOOR_N}², f64, laplacian, rtol {FLOOR_RTOL:e}");
    let why_not = |method: &str| -> String {
        match floor_row(rows, method) {
            None => format!("no {method} run at {at} in this sweep"),
            Some(r) => match &r.error {
                Some(e) => format!("{method} failed: {e}"),
                None => String::new(),
            },
        }
    };
    let err_note = |method: &str, row: Option<&ResultRow>| {
        let w = why_not(method);
        if w.is_empty() && row.and_then(|r| r.grad_rel_err).is_none() {
            "no exact reference gradient in this run, or a non-finite gradient".to_string()
        } else {
            w
        }
    };
    let both = naive.zip(implicit);
    let note_both = || {
        [why_not("naive"), why_not("implicit")]
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
            note: err_note("naive", naive),
        },
        Floor {
            key: "implicit_grad_err".into(),
            description: format!("implicit gradient error vs exact ({at})"),
            measured: worst_err(implicit),
            limit: 1e-6,
            at_least: false,
            note: err_note("implicit", implicit),
        },
        Floor {
            key: "implicit_backward_over_forward".into(),
            description: format!("implicit backward / forward time ({at})"),
            measured: backward_ratio,
            limit: 1.2,
            at_least: false,
            note: why_not("implicit"),
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

const MIB: f64 = 1024.0 * 1024.0;

pub(crate) fn write_chart(
    out_dir: &Path,
    file: &str,
    caption: &str,
    chart: LineChart<'_>,
    charts: &mut Vec<(String, String)>,
    notes: &mut Vec<String>,
) {
    match line_chart_svg(&out_dir.join(file), &chart) {
        Ok(()) => charts.push((file.to_string(), caption.to_string())),
        Err(e) => notes.push(format!("chart {file} not drawn: {e}")),
    }
}

/// Groups `rows` into one series per `method precision`, in a fixed method order
/// so colours match across charts.
pub(crate) fn series_by_method<'a>(
    rows: impl Iterator<Item = &'a ResultRow>,
    point: impl Fn(&ResultRow) -> Option<(f64, f64)>,
) -> Vec<Series> {
    const ORDER: [&str; 4] = ["naive", "implicit", "exact", "baseline_cg"];
    // (method order, label) → points
    type Group = ((usize, String), Vec<(f64, f64)>);
    let mut groups: Vec<Group> = Vec::new();
    for r in rows {
        let Some(p) = point(r) else { continue };
        let key = (
            ORDER
                .iter()
                .position(|m| *m == r.method)
                .unwrap_or(ORDER.len()),
            r.series_label(),
        );
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, pts)) => pts.push(p),
            None => groups.push((key, vec![p])),
        }
    }
    groups.sort_by(|a, b| a.0.cmp(&b.0));
    groups
        .into_iter()
        .map(|((_, label), mut pts)| {
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series::new(label, pts)
        })
        .collect()
}

/// Draws the harness's charts into `out_dir` from `rows`: gradient error vs
/// time, gradient error vs the reached residual of tolerance runs, peak memory
/// vs iterations, time vs grid size, and the stability map
/// (error, or non-finite, against fixed iteration counts). Returns the charts
/// drawn (file, caption) and notes on those that could not be.
pub fn write_charts(out_dir: &Path, rows: &[ResultRow]) -> (Vec<(String, String)>, Vec<String>) {
    let mut charts = Vec::new();
    let mut notes = Vec::new();
    let laplacian_label = OperatorKind::Laplacian.label();
    let laplacian = laplacian_label.as_str();
    // Per-size charts use the largest size at which the naive method ran.
    let chart_n = rows
        .iter()
        .filter(|r| r.method == "naive" && r.error.is_none() && r.operator == laplacian)
        .map(|r| r.n)
        .max()
        .or_else(|| rows.iter().map(|r| r.n).max())
        .unwrap_or(0);
    let gradient_rows = || {
        rows.iter()
            .filter(move |r| r.n == chart_n && r.operator == laplacian)
            .filter(|r| r.method != "baseline_cg")
    };

    let caption = format!("Gradient error vs time ({chart_n}², laplacian)");
    // The exact f64 row has error 0, which a log axis cannot place.
    let series = series_by_method(
        gradient_rows().filter(|r| r.grad_rel_err.is_some_and(|e| e > 0.0)),
        |r| Some((r.total_s()?, r.grad_rel_err?)),
    );
    write_chart(
        out_dir,
        "error_vs_time.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "forward + backward time (s)",
            y_label: "relative gradient error vs exact",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    // Tolerance runs placed at the residual they reached, not the one asked
    // for: below the rounding floor of a precision the two differ.
    let caption = format!("Gradient error vs reached residual ({chart_n}², laplacian)");
    let series = series_by_method(
        gradient_rows().filter(|r| {
            r.rtol.is_some() && r.grad_rel_err.is_some_and(|e| e > 0.0) && r.method != "exact"
        }),
        |r| Some((r.reached_relative_residual?, r.grad_rel_err?)),
    );
    write_chart(
        out_dir,
        "error_vs_residual.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "reached relative residual ‖b − A p‖/‖b‖ (tolerance runs)",
            y_label: "relative gradient error vs exact",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = format!("Peak heap vs CG iterations ({chart_n}², laplacian)");
    let series = series_by_method(
        gradient_rows().filter(|r| r.rtol.is_none() && r.method != "exact"),
        |r| Some((r.iterations? as f64, r.peak_heap_bytes? as f64 / MIB)),
    );
    write_chart(
        out_dir,
        "memory_vs_iterations.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "CG iterations",
            y_label: "peak heap (MiB)",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let tightest = rows
        .iter()
        .filter_map(|r| r.rtol)
        .fold(f64::INFINITY, f64::min);
    let caption = format!("Gradient time vs grid size (laplacian, rtol {tightest:e})");
    let series = series_by_method(
        // The baseline is forward-only; its comparison is the per-iteration floor.
        rows.iter().filter(|r| {
            r.operator == laplacian
                && r.method != "baseline_cg"
                && (r.rtol == Some(tightest) || r.method == "exact")
        }),
        |r| Some((r.n as f64, r.total_s()?)),
    );
    write_chart(
        out_dir,
        "time_vs_size.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "grid size n (n × n cells)",
            y_label: "forward + backward time (s)",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption =
        format!("Stability: gradient error vs fixed CG iterations ({chart_n}², laplacian)");
    let series = series_by_method(
        gradient_rows().filter(|r| r.rtol.is_none() && r.method != "exact"),
        |r| {
            let iters = r.max_iters? as f64;
            let shown = if r.finite { r.grad_rel_err? } else { f64::NAN };
            Some((iters, shown))
        },
    );
    write_chart(
        out_dir,
        "stability.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "CG iterations",
            y_label: "relative gradient error (× = non-finite)",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );
    (charts, notes)
}

/// Creates the output folder.
///
/// # Errors
/// [`CompareError::Io`].
pub fn prepare_out_dir(out: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(out).map_err(|e| CompareError::io(out, e))?;
    Ok(out.to_path_buf())
}
