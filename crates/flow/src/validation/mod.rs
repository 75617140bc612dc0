//! The validation flows: each builds its scene, runs it and compares the
//! result with an exact solution or a published table, and says in a typed
//! result whether its floors are met.
//!
//! | flow | reference | result |
//! | --- | --- | --- |
//! | [`TaylorGreen`] | the analytic decaying vortex | [`OrderStudy`]: errors and observed orders |
//! | [`Cavity`] | Ghia, Ghia and Shin 1982 ([`GHIA_1982`]) | [`CavityResult`]: centrelines and deviations |
//! | [`Dfg2d1`], [`Dfg2d2`] | Schäfer and Turek 1996 ([`DFG_2D1`], [`DFG_2D2`]) | [`SteadyCylinder`], [`PeriodicCylinder`] |
//!
//! The cylinder's forces are reported by two methods: the surface integral over
//! the staircase body and the momentum balance over a box around it
//! ([`control_volume_force`] on a [`FaceBox`]).
//!
//! The published tables are constants here, with their citations; a floor is
//! a [`FloorCheck`] (the quantity, its value, the limit and where the limit
//! comes from), and a result's `floors_met()` is what an example's exit
//! status and a test's assertion follow.
//!
//! ```
//! use diffphys_flow::validation::Cavity;
//!
//! // Re = 100 on 16 × 16 cells, stopped early: a smoke run of the comparison.
//! let result = Cavity::new(100, 16)?.max_time(0.5).run()?;
//! assert_eq!(result.ghia_u.len(), 17);
//! assert!(!result.run.steady);
//! # Ok::<(), diffphys_flow::FlowError>(())
//! ```

mod cavity;
mod control_volume;
mod cylinder;
mod dfg_forces;
mod pbdl_wake;
mod shedding;
mod taylor_green;

pub use cavity::{Cavity, CavityResult, GhiaTable, SuspectPoint, GHIA_1982, GHIA_X, GHIA_Y};
pub use control_volume::{
    control_volume_force, ControlVolumeForce, FaceBox, CONTROL_VOLUME_CLEARANCE,
};
pub use cylinder::{
    Dfg2d1, Dfg2d1Reference, Dfg2d2, Dfg2d2Reference, DfgChannel, PeriodicCylinder, SteadyCylinder,
    DFG_2D1, DFG_2D1_HIGH_ACCURACY, DFG_2D2, DFG_CENTRE, DFG_DIAMETER, DFG_HEIGHT, DFG_LENGTH,
    DFG_NU,
};
pub use pbdl_wake::pbdl_wake;
pub use shedding::Shedding;
pub use taylor_green::{OrderStudy, TaylorGreen};

use ndarray::Array2;

use crate::{FlowError, FlowState, Result, Scene};

/// A published reference interval `[lo, hi]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// The lower bound.
    pub lo: f64,
    /// The upper bound.
    pub hi: f64,
}

impl Interval {
    /// How far `x` lies outside the interval, relative to the nearer bound
    /// (0 inside; infinite for a NaN).
    pub fn outside(&self, x: f64) -> f64 {
        if x.is_nan() {
            f64::INFINITY
        } else if x < self.lo {
            (self.lo - x) / self.lo.abs()
        } else if x > self.hi {
            (x - self.hi) / self.hi.abs()
        } else {
            0.0
        }
    }
}

/// One floor of a validation run: a quantity, its value and its limit.
#[derive(Debug, Clone, PartialEq)]
pub struct FloorCheck {
    /// What is measured (`max |u - u_Ghia|`, `Strouhal error`, ...).
    pub quantity: String,
    /// The value the run gave.
    pub value: f64,
    /// The limit.
    pub limit: f64,
    /// Whether the value must stay at or below the limit (else at or above).
    pub at_most: bool,
    /// Where the limit comes from.
    pub source: &'static str,
}

impl FloorCheck {
    /// `value ≤ limit`.
    pub fn at_most(quantity: &str, value: f64, limit: f64, source: &'static str) -> Self {
        FloorCheck {
            quantity: quantity.to_string(),
            value,
            limit,
            at_most: true,
            source,
        }
    }

    /// `value ≥ limit`.
    pub fn at_least(quantity: &str, value: f64, limit: f64, source: &'static str) -> Self {
        FloorCheck {
            at_most: false,
            ..Self::at_most(quantity, value, limit, source)
        }
    }

    /// Whether the value is on the right side of the limit (a NaN never is).
    pub fn met(&self) -> bool {
        if self.at_most {
            self.value <= self.limit
        } else {
            self.value >= self.limit
        }
    }
}

impl std::fmt::Display for FloorCheck {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} = {:.4e} {} {:.4e} ({}): {}",
            self.quantity,
            self.value,
            if self.at_most { "<=" } else { ">=" },
            self.limit,
            self.source,
            if self.met() { "met" } else { "NOT met" }
        )
    }
}

/// Whether every floor of `floors` is met (true for none).
pub fn all_met(floors: &[FloorCheck]) -> bool {
    floors.iter().all(FloorCheck::met)
}

/// Called after each window of a steady run with `(steps, state, rate)`.
pub type Observer<'a> = dyn FnMut(usize, &FlowState<f64>, f64) -> Result<()> + 'a;

/// When a run towards a steady state stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SteadyStop {
    /// Steady when no face changes by more than `tol` per unit time.
    pub tol: f64,
    /// The latest time to stop at, steady or not.
    pub max_time: f64,
    /// Steps between two looks at the rate of change.
    pub window: usize,
}

/// A run towards a steady state.
#[derive(Debug, Clone)]
pub struct SteadyRun {
    /// The last state.
    pub state: FlowState<f64>,
    /// Steps taken.
    pub steps: usize,
    /// The time reached.
    pub time: f64,
    /// The largest change of a face per unit time over the last window.
    pub rate: f64,
    /// Whether `rate < tol`.
    pub steady: bool,
    /// Substeps taken (equal to `steps` without substepping).
    pub substeps: usize,
    /// CG iterations of the pressure solves, summed (0 for the direct solver).
    pub pressure_iterations: usize,
}

/// Runs `scene` from `start` without a tape until it is steady or `max_time`
/// is reached; `observe(steps, state, rate)` is called after each window.
///
/// # Errors
/// [`FlowError::InvalidParameter`] for a `tol`, `max_time` or `window` that is
/// not positive; the errors of [`Scene::forward`] and of `observe`.
pub fn run_to_steady(
    scene: &Scene,
    start: FlowState<f64>,
    stop: SteadyStop,
    observe: &mut Observer<'_>,
) -> Result<SteadyRun> {
    positive("steady run", "tol", stop.tol)?;
    positive("steady run", "max_time", stop.max_time)?;
    if stop.window == 0 {
        return Err(FlowError::parameter(
            "steady run",
            "window",
            "at least one step",
        ));
    }
    let (params, dt) = (scene.params(), scene.dt());
    let mut state = start;
    let mut mark = state.clone();
    let (mut steps, mut rate, mut substeps, mut iterations) = (0, f64::INFINITY, 0, 0);
    while (steps as f64) * dt < stop.max_time {
        let (next, info) = scene.forward(&state, &params)?;
        substeps += info.substeps;
        iterations += info.pressure_iterations.iter().sum::<usize>();
        state = next;
        steps += 1;
        if steps % stop.window == 0 {
            rate = largest_change(&state, &mark) / (stop.window as f64 * dt);
            mark = state.clone();
            observe(steps, &state, rate)?;
            if rate < stop.tol {
                break;
            }
        }
    }
    Ok(SteadyRun {
        state,
        steps,
        time: steps as f64 * dt,
        steady: rate < stop.tol,
        rate,
        substeps,
        pressure_iterations: iterations,
    })
}

/// The largest change of any velocity face between two states.
pub fn largest_change(a: &FlowState<f64>, b: &FlowState<f64>) -> f64 {
    let d = |p: &Array2<f64>, q: &Array2<f64>| {
        p.iter()
            .zip(q)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
    };
    d(&a.ux, &b.ux).max(d(&a.uy, &b.uy))
}

/// Observed orders of convergence of `errors` on grids of `n` cells (per
/// length): `ln(e_k / e_{k+1}) / ln(n_{k+1} / n_k)`, `None` where an error
/// is not positive.
pub fn observed_orders(n: &[usize], errors: &[f64]) -> Vec<Option<f64>> {
    (1..errors.len().min(n.len()))
        .map(|k| {
            let (e0, e1) = (errors[k - 1], errors[k]);
            (e0 > 0.0 && e1 > 0.0).then(|| (e0 / e1).ln() / (n[k] as f64 / n[k - 1] as f64).ln())
        })
        .collect()
}

/// `Ok` for a finite `value > 0`, else a typed error naming `quantity`.
fn positive(step: &str, quantity: &str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(FlowError::parameter(
            step,
            quantity,
            format!("must be finite and positive, got {value}"),
        ))
    }
}
