//! One fit loop for every coupling: Adam on a loss the caller records, a
//! learning-rate schedule, validation every few steps, and the parameters of
//! the best validation score kept (early stopping).
//!
//! The couplings differ only in what one step's loss is (a corrector unrolled
//! through the solver, a network fitted to pairs, an initial guess through CG
//! iterations) and what a validation measures; [`Fit::run`] takes both as
//! closures, so [`Trainer`](crate::Trainer),
//! [`SupervisedTrainer`](crate::SupervisedTrainer) and
//! [`GuessTrainer`](crate::guess::GuessTrainer) share one loop.
//!
//! ```
//! use diffphys_learn::fit::{Fit, Validation};
//! use diffphys_learn::LrSchedule;
//! use diffphys_nn::Params;
//! use diffphys_tape::ArrayD;
//!
//! // Fit w to 3 by Adam on (w - 3)²; validation is the distance to 3.
//! let mut params = Params::new();
//! params.add("w", ArrayD::zeros(vec![1]))?;
//! let fit = Fit { steps: 200, learning_rate: 0.1, schedule: LrSchedule::Constant,
//!     validate_every: 50, validation: Validation::FromUntrained };
//! let fitted = fit.run("toy", params,
//!     |_, tape, p| Ok(p.vars()[0].sub(tape.constant(ArrayD::from_elem(vec![1], 3.0)))?.powi(2)?.sum()?),
//!     |p| Ok((p.values()[0][[0]] - 3.0).abs()),
//!     &|| {})?;
//! assert_eq!(fitted.curve[0].0, 0); // the untrained parameters were validated
//! assert!(fitted.validation < 0.1);
//! # Ok::<(), diffphys_learn::LearnError>(())
//! ```

use std::time::Instant;

use diffphys_nn::{check_loss, Bound, Params};
use diffphys_tape::pool::BufferPool;
use diffphys_tape::{Adam, Tape, Var};

use crate::metrics::improves;
use crate::strategy::LrSchedule;
use crate::{LearnError, Result};

/// What is validated, and what a failed validation does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Validation {
    /// After training steps only; a validation that fails ends the fit with
    /// its error.
    Strict,
    /// The untrained parameters too (step 0: a training that only made the
    /// model worse returns the model it started from; a failure there is a
    /// [`LearnError::Selection`]: nothing to stop early against). Later, a
    /// validation that fails or scores NaN scores `+∞`, is listed in
    /// [`Fitted::failures`], and training goes on.
    FromUntrained,
}

/// The fit loop's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fit {
    /// Adam steps.
    pub steps: usize,
    /// Adam's initial step size.
    pub learning_rate: f64,
    /// How it changes over the steps.
    pub schedule: LrSchedule,
    /// Validate every this many steps (and after the last); 0 validates after
    /// the last only (no early stopping).
    pub validate_every: usize,
    /// What is validated and how a failure is taken.
    pub validation: Validation,
}

/// What a fit produced.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// The parameters of the best validation score.
    pub params: Params<f64>,
    /// The training loss at every step.
    pub losses: Vec<f64>,
    /// `(step, validation score)` at every validation.
    pub curve: Vec<(usize, f64)>,
    /// The step whose parameters were kept (0: the untrained ones).
    pub best_step: usize,
    /// Their validation score.
    pub validation: f64,
    /// The validations that failed, `(step, message)` (only with
    /// [`Validation::FromUntrained`]).
    pub failures: Vec<(usize, String)>,
    /// Seconds spent in the steps (loss, gradient, update), validation not
    /// included.
    pub seconds: f64,
}

impl Fit {
    /// Fits `params`: each step records `loss(step, tape, bound)` on a fresh
    /// tape (the steps' tapes share one buffer pool, freed when the fit ends),
    /// takes its gradient and an Adam step at the schedule's rate, then runs
    /// `tick`; `validate(params)` scores the parameters (lower is better).
    /// `who` names the caller in errors.
    ///
    /// # Errors
    /// [`LearnError::ZeroIterations`] for 0 steps; a non-finite loss
    /// ([`diffphys_nn::NnError::NonFiniteLoss`]); whatever `loss` returns;
    /// whatever `validate` returns with [`Validation::Strict`]; with
    /// [`Validation::FromUntrained`], [`LearnError::Selection`] if the
    /// untrained parameters' validation fails.
    pub fn run<F, V>(
        &self,
        who: &'static str,
        mut params: Params<f64>,
        mut loss: F,
        mut validate: V,
        tick: &dyn Fn(),
    ) -> Result<Fitted>
    where
        F: for<'t> FnMut(usize, &'t Tape<f64>, &Bound<'t, f64>) -> Result<Var<'t, f64>>,
        V: FnMut(&Params<f64>) -> Result<f64>,
    {
        if self.steps == 0 {
            return Err(LearnError::ZeroIterations { trainer: who });
        }
        let tolerant = self.validation == Validation::FromUntrained;
        let mut score = |params: &Params<f64>| -> Result<f64> {
            let s = validate(params)?;
            if tolerant && s.is_nan() {
                return Err(LearnError::invalid("validation", "the score is NaN"));
            }
            Ok(s)
        };
        let mut curve = Vec::new();
        let mut failures = Vec::new();
        let mut best: Option<(usize, f64, Params<f64>)> = None;
        if tolerant {
            let initial = score(&params).map_err(|e| LearnError::Selection {
                message: format!(
                    "{who}: the untrained model's validation already fails ({e}); there is \
                     nothing to stop early against"
                ),
            })?;
            curve.push((0, initial));
            best = Some((0, initial, params.clone()));
        }
        let mut adam = Adam::new(self.learning_rate);
        let mut losses = Vec::with_capacity(self.steps);
        let mut seconds = 0.0;
        let pool = BufferPool::new();
        for step in 0..self.steps {
            let start = Instant::now();
            let tape = Tape::with_pool(&pool);
            let p = params.bind(&tape);
            let l = loss(step, &tape, &p)?;
            losses.push(check_loss(step, l.item()?)?);
            let grads = tape.backward(l, p.vars())?;
            adam.lr = self.schedule.at(self.learning_rate, step, self.steps);
            params.step(&mut adam, &grads, &p)?;
            seconds += start.elapsed().as_secs_f64();
            tick();
            let done = step + 1;
            let due = self.validate_every > 0 && done % self.validate_every == 0;
            if due || done == self.steps {
                let s = match score(&params) {
                    Ok(s) => s,
                    Err(e) if tolerant => {
                        failures.push((done, e.to_string()));
                        f64::INFINITY
                    }
                    Err(e) => return Err(e),
                };
                curve.push((done, s));
                if improves(s, best.as_ref().map(|b| b.1)) {
                    best = Some((done, s, params.clone()));
                }
            }
        }
        // The last step always validates, so there is a best.
        let (best_step, validation, params) =
            best.ok_or(LearnError::ZeroIterations { trainer: who })?;
        Ok(Fitted {
            params,
            losses,
            curve,
            best_step,
            validation,
            failures,
            seconds,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffphys_tape::ArrayD;

    fn one(value: f64) -> Params<f64> {
        let mut p = Params::new();
        p.add("w", ArrayD::from_elem(vec![1], value)).unwrap();
        p
    }

    fn fit(validation: Validation) -> Fit {
        Fit {
            steps: 10,
            learning_rate: 0.5,
            schedule: LrSchedule::Constant,
            validate_every: 2,
            validation,
        }
    }

    /// `(w - 3)²`.
    fn to_three<'t>(tape: &'t Tape<f64>, p: &Bound<'t, f64>) -> Result<Var<'t, f64>> {
        let three = tape.constant(ArrayD::from_elem(vec![1], 3.0));
        Ok(p.vars()[0].sub(three)?.powi(2)?.sum()?)
    }

    #[test]
    fn a_fit_that_only_makes_things_worse_keeps_the_untrained_parameters() {
        // Validation prefers w = 0, where it starts; training moves w to 3.
        let fitted = fit(Validation::FromUntrained)
            .run(
                "test",
                one(0.0),
                |_, t, p| to_three(t, p),
                |p| Ok(p.values()[0][[0]].abs()),
                &|| {},
            )
            .unwrap();
        assert_eq!(fitted.best_step, 0);
        assert_eq!(fitted.params.values()[0][[0]], 0.0);
        assert_eq!(fitted.curve.len(), 6);
        assert_eq!(fitted.losses.len(), 10);
        // Strict: the untrained parameters are not a candidate.
        let strict = fit(Validation::Strict)
            .run(
                "test",
                one(0.0),
                |_, t, p| to_three(t, p),
                |p| Ok(p.values()[0][[0]].abs()),
                &|| {},
            )
            .unwrap();
        assert_eq!(strict.best_step, 2);
        assert_eq!(strict.curve.len(), 5);
    }

    #[test]
    fn failed_validations_are_listed_or_fatal_as_asked() {
        let failing_after = |limit: usize| {
            let mut calls = 0;
            move |_: &Params<f64>| {
                calls += 1;
                if calls > limit {
                    Err(LearnError::invalid("validation", "diverged"))
                } else {
                    Ok(1.0 / calls as f64)
                }
            }
        };
        let fitted = fit(Validation::FromUntrained)
            .run(
                "test",
                one(0.0),
                |_, t, p| to_three(t, p),
                failing_after(3),
                &|| {},
            )
            .unwrap();
        assert_eq!(fitted.failures.len(), 3);
        assert_eq!(fitted.failures[0].0, 6);
        assert_eq!(fitted.best_step, 4);
        assert!(fitted.curve.iter().skip(3).all(|c| c.1 == f64::INFINITY));
        let strict = fit(Validation::Strict).run(
            "test",
            one(0.0),
            |_, t, p| to_three(t, p),
            failing_after(3),
            &|| {},
        );
        assert!(matches!(strict, Err(LearnError::Invalid { .. })));
        let untrained = fit(Validation::FromUntrained).run(
            "test",
            one(0.0),
            |_, t, p| to_three(t, p),
            failing_after(0),
            &|| {},
        );
        assert!(matches!(untrained, Err(LearnError::Selection { .. })));
    }

    #[test]
    fn zero_steps_and_non_finite_losses_are_refused() {
        let zero = Fit {
            steps: 0,
            ..fit(Validation::Strict)
        };
        let r = zero.run(
            "test",
            one(0.0),
            |_, t, p| to_three(t, p),
            |_| Ok(0.0),
            &|| {},
        );
        assert!(matches!(
            r,
            Err(LearnError::ZeroIterations { trainer: "test" })
        ));
        let nan = fit(Validation::Strict).run(
            "test",
            one(0.0),
            |_, t, p| {
                let nan = t.constant(ArrayD::from_elem(vec![1], f64::NAN));
                Ok(p.vars()[0].sub(nan)?.powi(2)?.sum()?)
            },
            |_| Ok(0.0),
            &|| {},
        );
        // The tape refuses the non-finite value where it appears (the loop's own
        // check is the backstop for a loss that overflows in its last op).
        assert!(
            matches!(nan, Err(LearnError::Tape(_) | LearnError::Nn(_))),
            "{nan:?}"
        );
    }
}
