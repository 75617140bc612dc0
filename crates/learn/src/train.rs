//! The corrector trainer: one loop for every [`Strategy`], equal budgets, early
//! stopping on the validation split.

use std::rc::Rc;

use diffphys_nn::{Bound, Params};
use diffphys_tape::{ArrayD, Tape, Var};
use rand::rngs::StdRng;
use rand::Rng;

use crate::data::{Split, TrainSeed, Trained};
use crate::fit::{Fit, Validation};
use crate::hybrid::{physical_fields, Corrector, Hybrid, Simulator};
use crate::metrics::{rollout, Trajectory};
use crate::state::State;
use crate::strategy::{Budget, LrSchedule, Strategy};
use crate::{LearnError, Result};

/// One training batch: the (possibly perturbed) start states and the reference
/// states after each of the unroll's steps.
#[derive(Debug, Clone)]
pub struct Batch {
    /// The start states, a batch of `windows`.
    pub start: State,
    /// `targets[j]`: the reference's physical fields after step `j + 1`, each
    /// `[windows, …]`.
    pub targets: Rc<Vec<Vec<ArrayD<f64>>>>,
}

/// What one training produced.
#[derive(Debug, Clone)]
pub struct TrainedCorrector {
    /// The strategy.
    pub strategy: Strategy,
    /// The parameters at the best validation score (early stopping).
    pub params: Params<f64>,
    /// The training loss at every iteration.
    pub losses: Vec<f64>,
    /// `(iteration, validation score)` at every validation, starting with the
    /// untrained model at iteration 0. A rollout that diverged (a step
    /// refused a non-finite state, or the error came out NaN) scores `+∞`.
    pub validation_curve: Vec<(usize, f64)>,
    /// The iteration whose parameters were kept: 0 if no training iteration
    /// validated better than the untrained model.
    pub best_iteration: usize,
    /// Their validation score: the mean relative L2 error of a rollout.
    pub validation: f64,
    /// The validations whose rollout failed, `(iteration, message)`: a
    /// corrector that drove the state to a non-finite value scores `+∞` there
    /// and training goes on.
    pub validation_failures: Vec<(usize, String)>,
}

/// Trains correctors: Adam on the strategy's loss for the budget's iterations,
/// validation rollouts every `validate_every` iterations, the parameters of the
/// best validation score kept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trainer {
    /// The budget every strategy gets.
    pub budget: Budget,
    /// Adam's initial step size.
    pub learning_rate: f64,
    /// How it changes over training.
    pub schedule: LrSchedule,
    /// Validate every this many iterations (and after the last); 0 validates
    /// after the last only (no early stopping).
    pub validate_every: usize,
    /// Steps of the validation rollouts.
    pub validation_steps: usize,
}

impl Trainer {
    /// Draws one batch for `strategy` from `train` for `simulator` (windows
    /// uniform over trajectories and start steps; for [`Strategy::Noise`], the
    /// start states perturbed by [`Simulator::perturb`]; the targets are the
    /// physical fields).
    ///
    /// # Errors
    /// As [`Budget::windows`]; [`LearnError::EmptySplit`] without training
    /// trajectories; [`LearnError::Invalid`] for trajectories shorter than the
    /// unroll or samples that do not stack.
    pub fn draw_batch<S: Simulator + ?Sized>(
        &self,
        simulator: &S,
        strategy: &Strategy,
        train: &[Trajectory],
        rng: &mut StdRng,
    ) -> Result<Batch> {
        let windows = self.budget.windows(strategy)?;
        if train.is_empty() {
            return Err(LearnError::EmptySplit {
                split: Split::Train,
                context: format!("training {strategy}"),
            });
        }
        let k = strategy.unroll();
        let shortest = train.iter().map(Vec::len).min().unwrap_or(0);
        if shortest < k + 1 {
            return Err(LearnError::invalid(
                "training data",
                format!("a trajectory of {shortest} states is too short for an unroll of {k}"),
            ));
        }
        let picks: Vec<(usize, usize)> = (0..windows)
            .map(|_| {
                let i = rng.random_range(0..train.len());
                (i, rng.random_range(0..train[i].len() - k))
            })
            .collect();
        let at = |j: usize| {
            let rows: Vec<_> = picks.iter().map(|&(i, t)| &train[i][t + j]).collect();
            State::stack(&rows)
        };
        let mut start = at(0)?;
        let sigma = strategy.sigma();
        if sigma > 0.0 {
            simulator.perturb(&mut start, sigma, rng);
        }
        let physical = physical_fields(simulator, start.fields.len());
        let targets = (1..=k)
            .map(|j| {
                let mut fields = at(j)?.fields;
                fields.truncate(physical);
                Ok(fields)
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Batch {
            start,
            targets: Rc::new(targets),
        })
    }

    /// Records the loss of `batch` under `strategy` on `tape`: the mean squared
    /// error averaged over the unroll's steps.
    ///
    /// # Errors
    /// Whatever the unroll returns.
    pub fn batch_loss<'t, S: Simulator + 'static, C: Corrector + 'static>(
        hybrid: &Hybrid<S, C>,
        tape: &'t Tape<f64>,
        params: &Bound<'t, f64>,
        strategy: &Strategy,
        batch: &Batch,
    ) -> diffphys_tape::Result<Var<'t, f64>> {
        let s0 = batch.start.constants(tape);
        hybrid.unrolled_loss(
            tape,
            params,
            &s0,
            Rc::clone(&batch.targets),
            strategy.schedule(),
        )
    }

    /// Trains `params` (the corrector's initial parameters) with `strategy` on
    /// `train`, validating on `validation`; `seed` drives the windows and the
    /// noise; `tick` runs after every iteration (a progress bar).
    ///
    /// # Errors
    /// [`LearnError::ZeroIterations`], [`LearnError::ZeroUnroll`],
    /// [`LearnError::Budget`] (see [`Budget::windows`]); [`LearnError::EmptySplit`]
    /// for an empty training or validation split; [`LearnError::CorrectorShape`]
    /// if the corrector's output does not have the state's shape; a non-finite
    /// loss ([`diffphys_nn::NnError::NonFiniteLoss`]); [`LearnError::Selection`]
    /// if the untrained model's validation rollout already fails (there is
    /// nothing to stop early against).
    #[allow(clippy::too_many_arguments)]
    pub fn train<S: Simulator + 'static, C: Corrector + 'static>(
        &self,
        hybrid: &Hybrid<S, C>,
        params: Params<f64>,
        strategy: Strategy,
        train: &[Trajectory],
        validation: &[Trajectory],
        seed: TrainSeed,
        tick: &dyn Fn(),
    ) -> Result<Trained<TrainedCorrector>> {
        self.budget.windows(&strategy)?;
        if validation.is_empty() {
            return Err(LearnError::EmptySplit {
                split: Split::Validation,
                context: format!("early stopping of {strategy}"),
            });
        }
        if self.validation_steps == 0 {
            return Err(LearnError::ZeroUnroll {
                what: "validation rollout",
            });
        }
        let mut rng = seed.sampling_rng();
        let simulator = hybrid.simulator();
        let probe = self.draw_batch(simulator, &strategy, train, &mut rng.clone())?;
        hybrid.check_shapes(&params, &probe.start)?;

        let fit = Fit {
            steps: self.budget.iterations,
            learning_rate: self.learning_rate,
            schedule: self.schedule,
            validate_every: self.validate_every,
            validation: Validation::FromUntrained,
        };
        let fitted = fit.run(
            "trainer",
            params,
            |_, tape, p| {
                let batch = self.draw_batch(simulator, &strategy, train, &mut rng)?;
                Ok(Self::batch_loss(hybrid, tape, p, &strategy, &batch)?)
            },
            |params| validation_score(hybrid, params, validation, self.validation_steps),
            tick,
        )?;
        Ok(Trained::new(TrainedCorrector {
            strategy,
            params: fitted.params,
            losses: fitted.losses,
            validation_curve: fitted.curve,
            best_iteration: fitted.best_step,
            validation: fitted.validation,
            validation_failures: fitted.failures,
        }))
    }
}

/// The mean relative L2 error of a validation rollout of the hybrid with
/// `params` (NaN where a state went non-finite without a step refusing it:
/// the fit loop lists that as a failure).
fn validation_score<S: Simulator + 'static, C: Corrector + 'static>(
    hybrid: &Hybrid<S, C>,
    params: &Params<f64>,
    validation: &[Trajectory],
    steps: usize,
) -> Result<f64> {
    Ok(rollout(hybrid, Some(params), validation, steps)?.mean())
}
