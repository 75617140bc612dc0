//! Training strategies as values, equal budgets, and learning-rate schedules.

use std::fmt;

use diffphys_tape::Schedule;
use rand::Rng;

use crate::{LearnError, Result};

/// How a corrector is trained (Um et al., *Solver-in-the-loop*, NeurIPS 2020).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Strategy {
    /// Supervised single steps from reference states (precomputed pairs).
    NonInteracting,
    /// As [`Strategy::NonInteracting`], with Gaussian noise of standard
    /// deviation `sigma` added to each input state.
    Noise {
        /// The noise's standard deviation.
        sigma: f64,
    },
    /// `unroll` steps of solver and corrector from a reference state, the loss
    /// averaged over every step, the unroll stored by `schedule`.
    SolverInTheLoop {
        /// Steps per window (at least 1).
        unroll: usize,
        /// How the unroll is stored (gradients are the same for every schedule).
        schedule: Schedule,
    },
}

impl Strategy {
    /// Hybrid steps per training window.
    pub fn unroll(&self) -> usize {
        match *self {
            Strategy::SolverInTheLoop { unroll, .. } => unroll,
            _ => 1,
        }
    }

    /// The storage schedule of the unroll ([`Schedule::Full`] for one step).
    pub fn schedule(&self) -> Schedule {
        match *self {
            Strategy::SolverInTheLoop { schedule, .. } => schedule,
            _ => Schedule::Full,
        }
    }

    /// The input noise's standard deviation (0 without noise).
    pub fn sigma(&self) -> f64 {
        match *self {
            Strategy::Noise { sigma } => sigma,
            _ => 0.0,
        }
    }

    /// A short name: `non`, `noise`, `sol_k`.
    pub fn name(&self) -> String {
        match *self {
            Strategy::NonInteracting => "non".into(),
            Strategy::Noise { .. } => "noise".into(),
            Strategy::SolverInTheLoop { unroll, .. } => format!("sol_{unroll}"),
        }
    }

    /// Checks the strategy's values.
    ///
    /// # Errors
    /// [`LearnError::ZeroUnroll`] for an unroll of 0; [`LearnError::Invalid`]
    /// for a negative or non-finite `sigma`.
    pub fn validate(&self) -> Result<()> {
        match *self {
            Strategy::SolverInTheLoop { unroll: 0, .. } => Err(LearnError::ZeroUnroll {
                what: "solver in the loop",
            }),
            Strategy::Noise { sigma } if !(sigma.is_finite() && sigma >= 0.0) => {
                Err(LearnError::invalid(
                    "noise",
                    format!("sigma must be finite and ≥ 0, got {sigma}"),
                ))
            }
            _ => Ok(()),
        }
    }
}

impl fmt::Display for Strategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

/// The budget every strategy gets: `iterations` optimizer steps of
/// `evaluations_per_iteration` network evaluations each, so a strategy that
/// unrolls `k` steps trains on `evaluations_per_iteration / k` windows per step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Budget {
    /// Optimizer steps.
    pub iterations: usize,
    /// Network evaluations per optimizer step.
    pub evaluations_per_iteration: usize,
}

impl Budget {
    /// Windows per optimizer step for `strategy`.
    ///
    /// # Errors
    /// [`LearnError::ZeroIterations`] for 0 iterations, [`LearnError::ZeroUnroll`]
    /// for an unroll of 0, [`LearnError::Budget`] if the unroll does not divide
    /// the evaluations per step.
    pub fn windows(&self, strategy: &Strategy) -> Result<usize> {
        if self.iterations == 0 {
            return Err(LearnError::ZeroIterations { trainer: "trainer" });
        }
        strategy.validate()?;
        let k = strategy.unroll();
        let e = self.evaluations_per_iteration;
        if e == 0 || e % k != 0 {
            return Err(LearnError::Budget {
                message: format!(
                    "{e} network evaluations per step cannot be shared into windows of {k} \
                     steps ({strategy}); choose an unroll that divides them"
                ),
            });
        }
        Ok(e / k)
    }
}

/// The learning rate over training.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LrSchedule {
    /// Constant.
    Constant,
    /// `lr · final_fraction^(step/steps)`.
    Exponential {
        /// The fraction of the initial rate reached at the end.
        final_fraction: f64,
    },
    /// `lr · (f + (1 − f)·½(1 + cos(π step/steps)))` with `f = final_fraction`.
    Cosine {
        /// The fraction of the initial rate reached at the end.
        final_fraction: f64,
    },
}

impl LrSchedule {
    /// The rate at `step` of `steps` from the initial rate `lr`.
    pub fn at(&self, lr: f64, step: usize, steps: usize) -> f64 {
        let progress = step as f64 / steps.max(1) as f64;
        match *self {
            LrSchedule::Constant => lr,
            LrSchedule::Exponential { final_fraction } => lr * final_fraction.powf(progress),
            LrSchedule::Cosine { final_fraction } => {
                let cosine = 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
                lr * (final_fraction + (1.0 - final_fraction) * cosine)
            }
        }
    }
}

/// A standard normal sample (Box–Muller).
pub fn standard_normal(rng: &mut impl Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}
