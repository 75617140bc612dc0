//! Supervised training of a network on input–target pairs, from a stream drawn
//! afresh at every step (the solver as a data generator) or from a fixed set,
//! with the same budget and early stopping on the validation split.

use std::time::Instant;

use diffphys_nn::{Layer, Params};
use diffphys_tape::{ArrayD, Tape};
use rand::rngs::StdRng;
use rand::Rng;

use crate::data::{Split, Trained};
use crate::fit::{Fit, Validation};
use crate::hybrid::frozen;
use crate::metrics::batch_of;
use crate::strategy::LrSchedule;
use crate::{LearnError, Result};

/// One training pair, each of the sample's shape (without the batch axis).
#[derive(Debug, Clone)]
pub struct Pair {
    /// The network's input.
    pub input: ArrayD<f64>,
    /// What it should output.
    pub target: ArrayD<f64>,
}

/// Where a step's batch comes from.
pub enum PairSource<'a> {
    /// Drawn afresh at every step (a solver producing pairs on the fly).
    Stream(&'a mut dyn FnMut(&mut StdRng) -> Result<Pair>),
    /// Picked uniformly from a fixed set.
    Fixed(&'a [Pair]),
}

/// What one supervised training produced.
#[derive(Debug, Clone)]
pub struct TrainedNet {
    /// The parameters at the best validation score.
    pub params: Params<f64>,
    /// The training loss per step.
    pub losses: Vec<f64>,
    /// `(step, validation mean squared error)` at every validation.
    pub validation_curve: Vec<(usize, f64)>,
    /// The step whose parameters were kept.
    pub best_step: usize,
    /// Their validation mean squared error.
    pub validation: f64,
    /// Seconds spent making batches (drawing and solving, or copying).
    pub seconds_data: f64,
    /// Seconds in the network's forward, backward and update.
    pub seconds_network: f64,
}

/// The mean squared error of `net` over `pairs`.
///
/// # Errors
/// [`LearnError::Invalid`] without pairs; whatever the network returns.
pub fn mean_squared_error<L: Layer<f64>>(
    net: &L,
    params: &Params<f64>,
    pairs: &[Pair],
) -> Result<f64> {
    let inputs: Vec<&ArrayD<f64>> = pairs.iter().map(|p| &p.input).collect();
    let targets: Vec<&ArrayD<f64>> = pairs.iter().map(|p| &p.target).collect();
    let tape = Tape::new();
    let y = net.forward(&frozen(&tape, params), tape.constant(batch_of(&inputs)?))?;
    Ok(y.sub(tape.constant(batch_of(&targets)?))?
        .powi(2)?
        .mean()?
        .item()?)
}

/// Trains a network on pairs with Adam, early stopping on validation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SupervisedTrainer {
    /// Optimizer steps.
    pub steps: usize,
    /// Pairs per step.
    pub batch: usize,
    /// Adam's initial step size.
    pub learning_rate: f64,
    /// How it changes over training.
    pub schedule: LrSchedule,
    /// Validate every this many steps (and after the last); 0: after the last only.
    pub validate_every: usize,
}

impl SupervisedTrainer {
    /// Trains `params` of `net` on batches from `source`; `rng` drives the
    /// stream or the picks; `tick` runs after every step.
    ///
    /// # Errors
    /// [`LearnError::ZeroIterations`] for 0 steps, [`LearnError::Budget`] for a
    /// batch of 0, [`LearnError::EmptySplit`] for an empty fixed set or
    /// validation split; a non-finite loss; whatever the source and the network
    /// return.
    #[allow(clippy::too_many_arguments)]
    pub fn train<L: Layer<f64>>(
        &self,
        net: &L,
        params: Params<f64>,
        mut source: PairSource<'_>,
        rng: &mut StdRng,
        validation: &[Pair],
        tick: &dyn Fn(),
    ) -> Result<Trained<TrainedNet>> {
        if self.steps == 0 {
            return Err(LearnError::ZeroIterations {
                trainer: "supervised trainer",
            });
        }
        if self.batch == 0 {
            return Err(LearnError::Budget {
                message: "a batch of 0 pairs per step".into(),
            });
        }
        if matches!(source, PairSource::Fixed(set) if set.is_empty()) {
            return Err(LearnError::EmptySplit {
                split: Split::Train,
                context: "a fixed training set".into(),
            });
        }
        if validation.is_empty() {
            return Err(LearnError::EmptySplit {
                split: Split::Validation,
                context: "early stopping of a supervised training".into(),
            });
        }
        let fit = Fit {
            steps: self.steps,
            learning_rate: self.learning_rate,
            schedule: self.schedule,
            validate_every: self.validate_every,
            validation: Validation::Strict,
        };
        let mut seconds_data = 0.0;
        let fitted = fit.run(
            "supervised trainer",
            params,
            |_, tape, p| {
                let start = Instant::now();
                let pairs: Vec<Pair> = match &mut source {
                    PairSource::Stream(draw) => {
                        (0..self.batch).map(|_| draw(rng)).collect::<Result<_>>()?
                    }
                    PairSource::Fixed(set) => (0..self.batch)
                        .map(|_| set[rng.random_range(0..set.len())].clone())
                        .collect(),
                };
                let inputs: Vec<&ArrayD<f64>> = pairs.iter().map(|p| &p.input).collect();
                let targets: Vec<&ArrayD<f64>> = pairs.iter().map(|p| &p.target).collect();
                let (x, target) = (batch_of(&inputs)?, batch_of(&targets)?);
                seconds_data += start.elapsed().as_secs_f64();
                Ok(net
                    .forward(p, tape.constant(x))?
                    .sub(tape.constant(target))?
                    .powi(2)?
                    .mean()?)
            },
            |params| mean_squared_error(net, params, validation),
            tick,
        )?;
        Ok(Trained::new(TrainedNet {
            params: fitted.params,
            losses: fitted.losses,
            validation_curve: fitted.curve,
            best_step: fitted.best_step,
            validation: fitted.validation,
            seconds_network: fitted.seconds - seconds_data,
            seconds_data,
        }))
    }
}
