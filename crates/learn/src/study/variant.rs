//! The variants of a correction study as typed labels: the uncorrected
//! solver, one-step training with and without input noise, and solver in the
//! loop over `k` steps. A study selects, groups and names its runs by these
//! values, never by parsing a label string.

use std::fmt;
use std::str::FromStr;

use diffphys_tape::Schedule;

use crate::{LearnError, Strategy};

/// One of the trained or untrained solvers of a correction study.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Variant {
    /// The solver alone (`src`): nothing is trained.
    Src,
    /// Supervised on one-step pairs (`non`).
    Non,
    /// As `Non`, with input noise (`noise`).
    Noise,
    /// Solver in the loop over `k` steps (`sol_k`).
    Sol(usize),
}

impl fmt::Display for Variant {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Variant::Src => f.write_str("src"),
            Variant::Non => f.write_str("non"),
            Variant::Noise => f.write_str("noise"),
            Variant::Sol(k) => write!(f, "sol_{k}"),
        }
    }
}

impl FromStr for Variant {
    type Err = LearnError;

    /// Parses `src`, `non`, `noise`, `solK` (`sol4`, `sol_4`, `sol-16`, …).
    ///
    /// # Errors
    /// [`LearnError::UnknownVariant`]; [`LearnError::ZeroUnroll`] for `sol0`.
    fn from_str(name: &str) -> Result<Self, LearnError> {
        let unknown = || LearnError::UnknownVariant {
            name: name.to_string(),
        };
        match name.trim() {
            "src" => Ok(Variant::Src),
            "non" => Ok(Variant::Non),
            "noise" => Ok(Variant::Noise),
            s => {
                let k: usize = s
                    .strip_prefix("sol")
                    .map(|k| k.trim_start_matches(['-', '_']))
                    .and_then(|k| k.parse().ok())
                    .ok_or_else(unknown)?;
                if k == 0 {
                    return Err(LearnError::ZeroUnroll {
                        what: "solver in the loop",
                    });
                }
                Ok(Variant::Sol(k))
            }
        }
    }
}

impl Variant {
    /// `src`, `non`, `noise`, `sol_k` (the [`Display`](fmt::Display) form).
    pub fn name(&self) -> String {
        self.to_string()
    }

    /// Steps of one training window: `k` for `sol_k`, 1 otherwise.
    pub fn unroll(&self) -> usize {
        match *self {
            Variant::Sol(k) => k,
            _ => 1,
        }
    }

    /// Whether this is a solver-in-the-loop variant (the ones whose unroll a
    /// study chooses on validation).
    pub fn is_sol(&self) -> bool {
        matches!(self, Variant::Sol(_))
    }

    /// The learning-rate family: `non` and `noise` share one rate (`"non"`),
    /// every `sol_k` another (`"sol"`); `src` has none.
    pub fn family(&self) -> Option<&'static str> {
        match self {
            Variant::Src => None,
            Variant::Non | Variant::Noise => Some("non"),
            Variant::Sol(_) => Some("sol"),
        }
    }

    /// Corrector evaluations per Adam step: the smallest multiple of the
    /// unroll that is at least `at_least`, so a step holds whole windows
    /// (`sol_16` with `at_least` 4: one window of 16).
    pub fn step_evaluations(&self, at_least: usize) -> usize {
        let k = self.unroll().max(1);
        k * at_least.max(1).div_ceil(k)
    }

    /// Adam steps of a training with a budget of `evaluations`: the budget
    /// over [`Variant::step_evaluations`], at least one step for any budget
    /// but 0 (which stays 0, for the trainer to refuse).
    pub fn adam_steps(&self, evaluations: usize, at_least: usize) -> usize {
        if evaluations == 0 {
            0
        } else {
            (evaluations / self.step_evaluations(at_least)).max(1)
        }
    }

    /// How this variant trains: `None` for `src`; `noise` with input noise
    /// of standard deviation `sigma`; `sol_k` storing its unroll in full up
    /// to `checkpoint` steps and checkpointed every `checkpoint` steps above
    /// (`None`: always in full).
    pub fn strategy(&self, sigma: f64, checkpoint: Option<usize>) -> Option<Strategy> {
        match *self {
            Variant::Src => None,
            Variant::Non => Some(Strategy::NonInteracting),
            Variant::Noise => Some(Strategy::Noise { sigma }),
            Variant::Sol(unroll) => Some(Strategy::SolverInTheLoop {
                unroll,
                schedule: match checkpoint {
                    Some(every) if unroll > every => Schedule::Every(every),
                    _ => Schedule::Full,
                },
            }),
        }
    }
}
