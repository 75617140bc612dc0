//! The trainings of a correction study: one job (a [`Variant`] at a size,
//! from a training seed, at a learning rate, with a budget of corrector
//! evaluations) trained by the library's one [`Trainer`], with a progress
//! bar and a line of figures, and the learning-rate pilots that choose each
//! family's rate on validation.
//!
//! A scene gives what its trainings share ([`Trainings`]: the simulator, how
//! to draw a corrector of a size from a seed, the splits, the noise scale and
//! the schedule) and the jobs; every variant then trains with the same budget
//! of corrector evaluations, each Adam step holding whole windows
//! ([`Variant::step_evaluations`]).

use std::time::Instant;

use diffphys_nn::Params;
use diffphys_report::progress_bar;
use serde_json::{json, Map, Value};

use super::{pilot_learning_rates, run_jobs, Pilots, Variant};
use crate::data::{TrainSeed, Trained};
use crate::{
    rollout_each, Budget, Corrector, Hybrid, LearnError, LrSchedule, Simulator, TrainedCorrector,
    Trainer, Trajectory,
};

/// One training: a variant at a size, from a training seed, at a learning
/// rate, with a budget.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrainJob<S> {
    /// How the corrector is trained.
    pub variant: Variant,
    /// The corrector's size.
    pub size: S,
    /// Initial parameters and sampling.
    pub seed: TrainSeed,
    /// The peak learning rate.
    pub lr: f64,
    /// The budget: corrector evaluations over the whole training.
    pub evaluations: usize,
}

/// A finished training: its job, the trained corrector, its wall time and
/// the kept parameters' validation error per validation trajectory.
#[derive(Debug)]
pub struct TrainedRun<S> {
    /// What was trained.
    pub job: TrainJob<S>,
    /// The trained corrector (early stopping's parameters).
    pub trained: Trained<TrainedCorrector>,
    /// Wall time of the training.
    pub seconds: f64,
    /// The kept parameters' validation error on each validation trajectory
    /// (each condition of the validation split).
    pub validation_per_condition: Vec<f64>,
}

/// A corrector of a size drawn from a training seed, with its parameters.
pub type NewCorrector<'a, C, S, E> =
    dyn Fn(S, TrainSeed) -> std::result::Result<(C, Params<f64>), E> + Sync + 'a;

/// What every training of one data seed shares; [`Trainings::train`] trains
/// a job.
pub struct Trainings<'a, Sim, C, S, E> {
    /// The solver the corrector is trained through (cloned per training).
    pub simulator: &'a Sim,
    /// Draws a corrector of a size from a training seed.
    pub corrector: &'a NewCorrector<'a, C, S, E>,
    /// How the learning rate changes over a training.
    pub schedule: LrSchedule,
    /// Corrector evaluations per Adam step, at least (rounded up to whole
    /// windows, [`Variant::step_evaluations`]).
    pub step_evaluations: usize,
    /// SOL unrolls longer than this are checkpointed every this many steps
    /// (`None`: stored in full).
    pub checkpoint: Option<usize>,
    /// Steps of the validation rollouts.
    pub validation_steps: usize,
    /// Validate every this many corrector evaluations.
    pub validation_evaluations: usize,
    /// The input noise of `noise`.
    pub sigma: f64,
    /// The training split.
    pub train: &'a [Trajectory],
    /// The validation split (early stopping).
    pub validation: &'a [Trajectory],
    /// Names the trainings in progress bars (`"data 1"`).
    pub label: String,
}

impl<Sim, C, S, E> Trainings<'_, Sim, C, S, E>
where
    Sim: Simulator + Clone + Sync + 'static,
    C: Corrector + 'static,
    S: Copy + std::fmt::Display + Send + Sync,
    E: From<LearnError> + Send,
{
    /// Trains `job` and measures the kept parameters on every validation
    /// trajectory; prints one line of its figures.
    ///
    /// # Errors
    /// [`LearnError::Invalid`] for `src` (nothing to train); whatever the
    /// corrector's constructor or [`Trainer::train`] returns.
    pub fn train(&self, job: &TrainJob<S>) -> std::result::Result<TrainedRun<S>, E> {
        let TrainJob {
            variant,
            size,
            seed,
            lr,
            evaluations,
        } = *job;
        let strategy = variant
            .strategy(self.sigma, self.checkpoint)
            .ok_or_else(|| LearnError::invalid("training", "src has nothing to train"))?;
        let per_step = variant.step_evaluations(self.step_evaluations);
        let iterations = variant.adam_steps(evaluations, self.step_evaluations);
        let trainer = Trainer {
            learning_rate: lr,
            budget: Budget {
                iterations,
                evaluations_per_iteration: per_step,
            },
            schedule: self.schedule,
            validate_every: (self.validation_evaluations / per_step).max(1),
            validation_steps: self.validation_steps,
        };
        let (corrector, params) = (self.corrector)(size, seed)?;
        let hybrid = Hybrid::new(self.simulator.clone(), corrector);
        let bar = progress_bar(
            iterations,
            &format!(
                "{} {variant:>6} {size} seed {} (lr {lr:.0e})",
                self.label, seed.0
            ),
        );
        let start = Instant::now();
        let trained = trainer.train(
            &hybrid,
            params,
            strategy,
            self.train,
            self.validation,
            seed,
            &|| bar.inc(1),
        )?;
        bar.finish_and_clear();
        let seconds = start.elapsed().as_secs_f64();
        let per_condition = rollout_each(
            &hybrid,
            Some(&trained.model.params),
            self.validation,
            self.validation_steps,
        )?;
        println!(
            "  {variant:>6} {size} seed {}, lr {lr:.0e}: {seconds:.1} s, validation {:.5} (kept iteration {} of {iterations}; per condition {})",
            seed.0,
            trained.model.validation,
            trained.model.best_iteration,
            per_condition
                .iter()
                .map(|e| format!("{e:.4}"))
                .collect::<Vec<_>>()
                .join(", "),
        );
        Ok(TrainedRun {
            job: *job,
            trained,
            seconds,
            validation_per_condition: per_condition,
        })
    }

    /// Trains `jobs` on `threads` workers; the runs in job order.
    ///
    /// # Errors
    /// The first failed training's, in job order.
    pub fn run(
        &self,
        jobs: &[TrainJob<S>],
        threads: usize,
    ) -> std::result::Result<Vec<TrainedRun<S>>, E> {
        run_jobs(jobs, threads, |job| self.train(job))
    }

    /// The learning rate of each family of `variants` (`non` for `non` and
    /// `noise`, `sol` for every SOL, piloted with the first SOL listed),
    /// chosen on validation: every family trained at every rate at `size`
    /// from `seed` with a budget of `evaluations`, on `threads` workers.
    /// With one rate nothing is trained.
    ///
    /// # Errors
    /// As [`pilot_learning_rates`] and [`Trainings::train`].
    pub fn learning_rates(
        &self,
        variants: &[Variant],
        rates: &[f64],
        (size, seed, evaluations): (S, TrainSeed, usize),
        threads: usize,
    ) -> std::result::Result<LearningRates, E> {
        let mut families: Vec<(&'static str, Variant)> = Vec::new();
        for &v in variants {
            if let Some(f) = v.family() {
                if families.iter().all(|(g, _)| *g != f) {
                    families.push((f, v));
                }
            }
        }
        // Non before SOL, whatever the order of the list.
        families.sort_by_key(|(f, _)| *f != "non");
        let pilots = pilot_learning_rates(&families, rates, |pilots| {
            let jobs: Vec<TrainJob<S>> = pilots
                .iter()
                .map(|&((_, variant), lr)| TrainJob {
                    variant,
                    size,
                    seed,
                    lr,
                    evaluations,
                })
                .collect();
            Ok::<_, E>(
                self.run(&jobs, threads)?
                    .iter()
                    .map(|r| r.trained.model.validation)
                    .collect(),
            )
        })?;
        let first = *rates
            .first()
            .ok_or_else(|| LearnError::invalid("learning rates", "no rate to choose from"))?;
        Ok(LearningRates {
            pilots: Pilots {
                chosen: pilots.chosen.iter().map(|&((f, _), lr)| (f, lr)).collect(),
                scores: pilots
                    .scores
                    .into_iter()
                    .map(|((f, _), s)| (f, s))
                    .collect(),
            },
            fallback: first,
        })
    }
}

/// The learning rate chosen per family ([`Trainings::learning_rates`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LearningRates {
    /// The pilots' scores and the rate chosen per family (`"non"`, `"sol"`).
    pub pilots: Pilots<&'static str>,
    /// The rate of a variant whose family was not piloted (the first rate).
    pub fallback: f64,
}

impl LearningRates {
    /// The rate `variant` trains at.
    pub fn of(&self, variant: Variant) -> f64 {
        variant
            .family()
            .and_then(|f| self.pilots.rate(f))
            .unwrap_or(self.fallback)
    }

    /// Prints each family's choice and adds it to `into` under
    /// `{family}_data_{label}` (the rate) and `{family}_pilots_data_{label}`
    /// (every pilot's rate and validation score).
    pub fn record(&self, label: impl std::fmt::Display, into: &mut Map<String, Value>) {
        for (family, scores) in &self.pilots.scores {
            if let Some(best) = self.pilots.rate(*family) {
                println!("  learning rate for {family}: {best:.0e} (pilot validation {scores:?})");
            }
            into.insert(
                format!("{family}_pilots_data_{label}"),
                json!(scores
                    .iter()
                    .map(|(lr, v)| json!({"lr": lr, "validation": v}))
                    .collect::<Vec<_>>()),
            );
        }
        for (family, lr) in &self.pilots.chosen {
            into.insert(format!("{family}_data_{label}"), json!(lr));
        }
    }
}
