//! The sweep: every scene with every method and stopping rule, each run a row,
//! runs that would not fit in memory or on the grid refused with a typed error.

use std::collections::HashMap;

use diffphys_tape::Real;
use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::alloc::CountingAllocator;
use crate::format::format_bytes;
use crate::memory::{MemoryBudget, Storage};
use crate::methods::exact::ExactCholesky;
use crate::methods::naive::NaiveUnrolled;
use crate::methods::{gradient_method, GradientMethod, Stop};
use crate::model::{Method, Precision, ResultRow};
use crate::npy::NpyWriter;
use crate::problem::{LossKind, OperatorKind, Problem, ProblemSpec};
use crate::progress::Progress;
use crate::{CompareError, Result};

use super::measure::{finite_difference_error, measure_baseline_with, measure_with};
use super::policy::TimingPolicy;

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
    /// Runs whose estimated memory exceeds this many MiB are refused (rows with
    /// [`CompareError::MemoryLimit`]); `None` checks against the memory the
    /// machine has available ([`crate::memory::MemoryBudget::new`]).
    #[serde(default)]
    pub memory_limit_mib: Option<usize>,
    /// The methods to run, from [`Method::SELECTABLE`] (each at most once; the
    /// sweep runs them in that order whatever the order here).
    #[serde(default = "all_methods")]
    pub methods: Vec<Method>,
    /// The warm-up and repetition policy of every timed run.
    #[serde(default)]
    pub timing: TimingPolicy,
}

fn all_methods() -> Vec<Method> {
    Method::SELECTABLE.to_vec()
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
            memory_limit_mib: None,
            methods: all_methods(),
            timing: TimingPolicy::default(),
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
            memory_limit_mib: None,
            methods: all_methods(),
            timing: TimingPolicy::quick(),
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
    /// tolerance not in `(0, 1)`, a zero iteration count or cap, a method that
    /// is not one of [`Method::SELECTABLE`], or no timed run in the policy.
    pub fn validate(&self) -> Result<()> {
        let fail = |m: String| Err(CompareError::invalid(m));
        if self.sizes.is_empty()
            || self.precisions.is_empty()
            || self.operators.is_empty()
            || self.methods.is_empty()
        {
            return fail(
                "sizes, precisions, operators and methods must each list at least one".into(),
            );
        }
        if let Some(m) = self
            .methods
            .iter()
            .find(|m| !Method::SELECTABLE.contains(m))
        {
            return fail(format!(
                "method '{m}' cannot be run by a sweep: choose from {}",
                Method::SELECTABLE.map(Method::name).join(", ")
            ));
        }
        self.timing.validate()?;
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

    /// True if the sweep runs `method`.
    pub fn runs(&self, method: Method) -> bool {
        self.methods.contains(&method)
    }

    /// Rows per scene: one each for exact and the baseline, one per stopping
    /// rule for each iterative gradient method, as selected.
    fn rows_per_scene(&self) -> usize {
        let once = [Method::Exact, Method::BaselineCg];
        let per_stop = [Method::Implicit, Method::ImplicitMgpcg, Method::Naive];
        let count = |ms: &[Method]| ms.iter().filter(|m| self.runs(**m)).count();
        count(&once) + count(&per_stop) * self.stops().len()
    }

    /// How many rows a sweep produces (for the progress bar).
    pub fn run_count(&self) -> usize {
        self.rows_per_scene() * self.sizes.len() * self.precisions.len() * self.operators.len()
    }
}

/// Bytes the naive tape holds per CG iteration: seven arrays of the grid.
pub fn naive_bytes_per_iteration<T: Real>(n: usize) -> usize {
    7 * n * n * std::mem::size_of::<T>()
}

/// The `f64` exact gradient of a scene, computed once per scene.
pub(crate) type ExactCache = HashMap<(usize, String), Option<Array2<f64>>>;

pub(crate) fn exact_reference(cache: &mut ExactCache, spec: ProblemSpec) -> Option<Array2<f64>> {
    cache
        .entry((spec.n, spec.operator.label()))
        .or_insert_with(|| {
            let problem = Problem::<f64>::new(spec).ok()?;
            ExactCholesky
                .run(&problem, Stop::Iterations(0))
                .ok()
                .map(|o| o.gradient)
        })
        .clone()
}

/// What a sweep writes as `.npy` files besides its rows: for the plain
/// Laplacian in `f64`, each size's `b`, target, exact gradient and every
/// method's gradient under every stopping rule.
struct NpySink<'a> {
    writer: &'a mut NpyWriter,
    first_error: Option<CompareError>,
}

impl NpySink<'_> {
    fn wants<T: Real>(spec: &ProblemSpec) -> bool {
        Precision::of::<T>() == Precision::F64 && spec.operator == OperatorKind::Laplacian
    }

    fn write<T: Real>(&mut self, name: &str, array: &Array2<T>, meaning: &str) {
        if self.first_error.is_some() {
            return;
        }
        let values = array.mapv(|v| v.as_f64()).into_dyn();
        if let Err(e) = self.writer.write(name, values.view(), meaning) {
            self.first_error = Some(e.into());
        }
    }
}

/// The `.npy` name of a stopping rule: `iters30`, `rtol1e-8`.
pub fn stop_label(stop: Stop) -> String {
    match stop {
        Stop::Iterations(k) => format!("iters{k}"),
        Stop::Tolerance { rtol, .. } => format!("rtol{rtol:e}"),
    }
}

/// A row of `method` that was not run, with the reason.
fn refused_row(
    method: Method,
    precision: Precision,
    spec: &ProblemSpec,
    stop: Option<Stop>,
    e: &CompareError,
) -> ResultRow {
    let mut row = ResultRow::new(method, precision, spec.n, spec.operator);
    row.rtol = stop.and_then(|s| s.rtol());
    row.max_iters = stop.map(|s| s.max_iters());
    row.fail(e);
    row
}

/// Forward CG iterations a plain (unpreconditioned) solve needs to reach
/// `rtol`, counting at most `cap`: to size a naive tape when no implicit or
/// baseline run said. Untimed. The cap keeps a solve whose tape could never fit
/// short: `Some(cap)` means at least that many.
fn plain_cg_iterations<T: Real>(problem: &Problem<T>, rtol: f64, cap: usize) -> Option<usize> {
    let stop = Stop::Tolerance {
        rtol,
        max_iters: cap.max(1),
    };
    let params = crate::methods::implicit::cg_params(stop)
        .with_null_space(problem.spec.operator.null_space());
    let mut x = ndarray::ArrayD::<T>::zeros(problem.b.shape());
    diffphys_ops::cg::conjugate_gradient(
        &problem.operator,
        problem.b.view().into_dyn(),
        x.view_mut(),
        &params,
    )
    .ok()
    .map(|info| info.iterations)
}

/// The progress message of one run: what runs, on what, under which policy.
fn run_message(label: &str, what: &str, policy: &TimingPolicy) -> String {
    format!(
        "{label} {what} ({} warm-up + {} timed)",
        policy.warmup, policy.repeats
    )
}

#[allow(clippy::too_many_arguments)]
fn sweep_scene<T: Real>(
    config: &SweepConfig,
    spec: ProblemSpec,
    exact: Option<&Array2<f64>>,
    heap: Option<&CountingAllocator>,
    budget: &MemoryBudget,
    bar: &dyn Progress,
    rows: &mut Vec<ResultRow>,
    mut npy: Option<&mut NpySink<'_>>,
) {
    let label = format!("{} {} n={}", spec.operator.label(), T::NAME, spec.n);
    let value_bytes = std::mem::size_of::<T>();
    let stops = config.stops();
    let per_scene = config.rows_per_scene();
    let policy = &config.timing;
    // A scene whose fields alone do not fit: every run of it is refused, each
    // with its own method's estimate.
    if budget
        .check(Method::Setup.name(), spec.n, value_bytes, Storage::Fields)
        .is_err()
    {
        let refuse = |method: Method, storage: Storage, stop: Option<Stop>| {
            let e = budget
                .check(method.name(), spec.n, value_bytes, storage)
                .expect_err("a run needs at least its scene's fields");
            refused_row(method, Precision::of::<T>(), &spec, stop, &e)
        };
        if config.runs(Method::Exact) {
            rows.push(refuse(Method::Exact, Storage::Cholesky, None));
        }
        if config.runs(Method::BaselineCg) {
            rows.push(refuse(Method::BaselineCg, Storage::Fields, None));
        }
        for &stop in &stops {
            for method in [Method::Implicit, Method::ImplicitMgpcg] {
                if config.runs(method) {
                    rows.push(refuse(method, Storage::Fields, Some(stop)));
                }
            }
            if config.runs(Method::Naive) {
                let iterations = stop.max_iters();
                rows.push(refuse(
                    Method::Naive,
                    Storage::NaiveTape { iterations },
                    Some(stop),
                ));
            }
        }
        bar.inc(per_scene as u64);
        return;
    }
    let problem = match Problem::<T>::new(spec) {
        Ok(p) => p,
        Err(e) => {
            let mut row =
                ResultRow::new(Method::Setup, Precision::of::<T>(), spec.n, spec.operator);
            row.fail(&e);
            rows.push(row);
            bar.inc(per_scene as u64);
            return;
        }
    };
    let failed_row = |method: Method, stop: Option<Stop>, e: CompareError| {
        refused_row(method, Precision::of::<T>(), &spec, stop, &e)
    };
    let n = spec.n;
    if let Some(sink) = npy.as_deref_mut().filter(|_| NpySink::wants::<T>(&spec)) {
        sink.write(
            &format!("n{n}_b"),
            &problem.b,
            "right-hand side b (the leaf)",
        );
        sink.write(
            &format!("n{n}_target"),
            &problem.target,
            "target p* of the loss ½‖p − p*‖²",
        );
        if let Some(g) = exact {
            sink.write(
                &format!("n{n}_grad_exact"),
                g,
                "dL/db by sparse Cholesky (f64 reference)",
            );
        }
    }

    let with_fd = n <= config.fd_max_n;
    let measure_fd = |m: &dyn GradientMethod<T>, stop: Option<Stop>| {
        let (mut row, out) = measure_with(policy, m, &problem, stop, heap, exact);
        if let (true, Some(out)) = (with_fd, &out) {
            let stop = stop.unwrap_or(Stop::Iterations(0));
            row.fd_rel_err = finite_difference_error(m, &problem, stop, &out.gradient);
        }
        (row, out.map(|o| o.gradient))
    };
    let mut record = |rows: &mut Vec<ResultRow>,
                      method: Method,
                      stop: Stop,
                      (row, gradient): (ResultRow, Option<Array2<T>>)| {
        if let (Some(sink), Some(g)) = (
            npy.as_deref_mut().filter(|_| NpySink::wants::<T>(&spec)),
            gradient,
        ) {
            let name = format!("n{n}_grad_{method}_{}", stop_label(stop));
            let meaning = format!("dL/db by the {method} method, {stop:?}");
            sink.write(&name, &g, &meaning);
        }
        rows.push(row);
    };
    if config.runs(Method::Exact) {
        bar.set_message(run_message(&label, "exact (sparse Cholesky)", policy));
        rows.push(
            match budget.check("exact", n, value_bytes, Storage::Cholesky) {
                Err(e) => failed_row(Method::Exact, None, e),
                Ok(()) => measure_fd(&ExactCholesky, None).0,
            },
        );
        bar.inc(1);
    }

    let tightest = config.rtols.iter().copied().fold(f64::INFINITY, f64::min);
    let baseline_stop = if tightest.is_finite() {
        Stop::Tolerance {
            rtol: tightest,
            max_iters: config.max_iters,
        }
    } else {
        Stop::Iterations(config.iters.iter().copied().max().unwrap_or(1))
    };
    // Iterations the tightest tolerance needs, to size naive tapes if the
    // implicit run cannot tell.
    let mut baseline_iters = None;
    if config.runs(Method::BaselineCg) {
        bar.set_message(run_message(&label, "baseline CG", policy));
        let baseline = match budget.check("baseline_cg", n, value_bytes, Storage::Fields) {
            Ok(()) => measure_baseline_with(policy, &problem, baseline_stop, heap),
            Err(e) => refused_row(
                Method::BaselineCg,
                Precision::of::<T>(),
                &spec,
                Some(baseline_stop),
                &e,
            ),
        };
        baseline_iters = baseline.iterations.filter(|_| baseline.error.is_none());
        rows.push(baseline);
        bar.inc(1);
    }

    for stop in stops {
        // The implicit run first: its iteration count sizes the naive tape.
        let mut implicit_iters = None;
        for method in [Method::Implicit, Method::ImplicitMgpcg] {
            let Some(gradient) = gradient_method::<T>(method).filter(|_| config.runs(method))
            else {
                continue;
            };
            bar.set_message(run_message(
                &label,
                &format!("{method} {}", stop_label(stop)),
                policy,
            ));
            match budget.check(method.name(), n, value_bytes, Storage::Fields) {
                Ok(()) => {
                    let measured = measure_fd(gradient.as_ref(), Some(stop));
                    if method == Method::Implicit {
                        implicit_iters = measured.0.iterations;
                    }
                    record(rows, method, stop, measured);
                }
                Err(e) => rows.push(failed_row(method, Some(stop), e)),
            }
            bar.inc(1);
        }
        if !config.runs(Method::Naive) {
            continue;
        }

        bar.set_message(run_message(
            &label,
            &format!("naive {}", stop_label(stop)),
            policy,
        ));
        // The iterations the naive tape will hold, and whether that is only a
        // lower bound (a count stopped at the tape limit).
        let (expected_iters, at_least) = match stop {
            Stop::Iterations(k) => (k, false),
            Stop::Tolerance { rtol, max_iters } => {
                match implicit_iters.or(baseline_iters) {
                    Some(k) => (k.min(max_iters), false),
                    None => {
                        // Neither implicit nor the baseline ran this rule: count
                        // the iterations of a plain solve, no further than one
                        // past what the tape limit allows (the scene's fields
                        // fit, as checked above).
                        let fit = config.naive_tape_limit_bytes
                            / naive_bytes_per_iteration::<T>(n).max(1);
                        let cap = max_iters.min(fit.saturating_add(1));
                        match plain_cg_iterations(&problem, rtol, cap) {
                            Some(k) => (k, k == cap && cap < max_iters),
                            None => (max_iters, false),
                        }
                    }
                }
            }
        };
        let unknowns = n * n;
        let estimate = expected_iters.saturating_mul(naive_bytes_per_iteration::<T>(n));
        let too_many = match stop {
            Stop::Iterations(k) if k > unknowns => Some(k),
            _ => None,
        };
        if let Some(k) = too_many {
            rows.push(failed_row(
                Method::Naive,
                Some(stop),
                CompareError::GridTooSmall {
                    method: "naive".into(),
                    n,
                    iterations: k,
                    unknowns,
                },
            ));
        } else if estimate > config.naive_tape_limit_bytes {
            rows.push(failed_row(
                Method::Naive,
                Some(stop),
                CompareError::Skipped(format!(
                    "{}{expected_iters} unrolled iterations would need a tape of {}{} (limit {})",
                    if at_least { "at least " } else { "~" },
                    if at_least { "more than " } else { "about " },
                    format_bytes(estimate),
                    format_bytes(config.naive_tape_limit_bytes)
                )),
            ));
        } else if let Err(e) = budget.check(
            "naive",
            n,
            value_bytes,
            Storage::NaiveTape {
                iterations: expected_iters,
            },
        ) {
            rows.push(failed_row(Method::Naive, Some(stop), e));
        } else {
            let measured = measure_fd(&NaiveUnrolled::default(), Some(stop));
            record(rows, Method::Naive, stop, measured);
        }
        bar.inc(1);
    }
}

/// Runs every scene of `config` with every method and stopping rule, returning
/// one row per run (failures included, as rows with an `error`). Runs whose
/// memory estimate exceeds the budget ([`SweepConfig::memory_limit_mib`]) are
/// rows with [`CompareError::MemoryLimit`], never attempted.
///
/// # Errors
/// [`CompareError::InvalidArgument`] if the configuration is invalid (see
/// [`SweepConfig::validate`]); method failures are rows, not errors.
pub fn run_sweep(
    config: &SweepConfig,
    heap: Option<&CountingAllocator>,
    progress: &dyn Progress,
) -> Result<Vec<ResultRow>> {
    sweep(config, heap, progress, None)
}

/// [`run_sweep`], also writing through `npy`, for the plain Laplacian in `f64`,
/// each size's `b` (`n{n}_b`), target (`n{n}_target`), exact gradient
/// (`n{n}_grad_exact`) and each method's gradient under each stopping rule
/// (`n{n}_grad_{method}_{stop}`, see [`stop_label`]). The caller finishes the
/// writer (its `index.json`).
///
/// # Errors
/// As [`run_sweep`], and the first failure to write an array.
pub fn run_sweep_npy(
    config: &SweepConfig,
    heap: Option<&CountingAllocator>,
    progress: &dyn Progress,
    npy: &mut NpyWriter,
) -> Result<Vec<ResultRow>> {
    let mut sink = NpySink {
        writer: npy,
        first_error: None,
    };
    let rows = sweep(config, heap, progress, Some(&mut sink))?;
    match sink.first_error {
        Some(e) => Err(e),
        None => Ok(rows),
    }
}

fn sweep(
    config: &SweepConfig,
    heap: Option<&CountingAllocator>,
    bar: &dyn Progress,
    mut npy: Option<&mut NpySink<'_>>,
) -> Result<Vec<ResultRow>> {
    config.validate()?;
    let budget = MemoryBudget::new(config.memory_limit_mib);
    bar.begin(config.run_count(), "sweep");
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
            let exact = match budget.check("exact", n, 8, Storage::Cholesky) {
                Ok(()) => exact_reference(&mut cache, spec),
                Err(_) => None,
            };
            for &precision in &config.precisions {
                let npy = npy.as_deref_mut();
                match precision {
                    Precision::F32 => sweep_scene::<f32>(
                        config,
                        spec,
                        exact.as_ref(),
                        heap,
                        &budget,
                        bar,
                        &mut rows,
                        npy,
                    ),
                    Precision::F64 => sweep_scene::<f64>(
                        config,
                        spec,
                        exact.as_ref(),
                        heap,
                        &budget,
                        bar,
                        &mut rows,
                        npy,
                    ),
                }
            }
        }
    }
    bar.finish();
    Ok(rows)
}
