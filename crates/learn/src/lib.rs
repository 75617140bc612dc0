//! # diffphys-learn
//!
//! Training networks through differentiable solvers, as a library: what every
//! solver-in-the-loop scene otherwise writes by hand.
//!
//! - A [`Simulator`] is a differentiable step `state → state` on the tape (plus a
//!   plain forward) of a [`State`]: several fields of their own shapes and
//!   per-sample parameters (a viscosity per sample); a [`Corrector`] is a
//!   network; their [`Hybrid`] step is the solver step, then the correction of
//!   the physical fields.
//! - Training strategies are values ([`Strategy::NonInteracting`],
//!   [`Strategy::Noise`], [`Strategy::SolverInTheLoop`] with a checkpoint
//!   [`Schedule`]); the [`Trainer`] gives each the same [`Budget`] of network
//!   evaluations and keeps the parameters of the best validation score, the
//!   untrained model's (iteration 0) included: a training that only made the
//!   model worse returns the model it started from. A validation rollout that
//!   fails or comes out NaN scores `+∞` and is listed, not fatal.
//! - Data are typed: a [`DataSeed`] derives the [`Split::Train`],
//!   [`Split::Validation`] and [`Split::HeldOut`] draws from separate streams;
//!   the held-out split ([`HeldOut`]) is read only through
//!   [`HeldOut::evaluate`], once per trained model, after [`select_best`] chose on
//!   validation.
//! - [`rollout`] measures the relative L2 error per step of an `n`-step rollout;
//!   a [`Report`] holds every run's figure and their mean, min and max over data
//!   seeds × training seeds.
//! - [`SupervisedTrainer`] fits a network to pairs a solver makes, on the fly
//!   or from a fixed set, with the same budget and early stopping on validation.
//! - [`guess`] trains a network's initial guess for conjugate gradient, with CG
//!   iterations as virtual time.
//! - A [`study::Plan`] of variants × sizes × training seeds runs several
//!   trainings at once ([`study::run_jobs`]) and groups them back for
//!   selection on typed labels; the held-out split counts its readings
//!   ([`HeldOut::readings`]).
//! - A [`cache::Cache`] keeps generated data (a reference solution) on disk
//!   between runs, keyed by every setting that shaped it.
//! - [`saved`] writes a trained model's parameters with the settings that
//!   shaped them ([`ModelCard`]) and refuses to load it into a scene whose
//!   settings differ ([`LearnError::SettingsMismatch`]).
//!
//! A corrector for a decaying state, trained with solver in the loop and
//! evaluated once on the held-out split:
//!
//! ```
//! use diffphys_learn::*;
//! use diffphys_nn::{Activation, Bound, Layer, Padding, Params, UNet, UNetConfig};
//! use diffphys_tape::{ArrayD, Schedule, Var};
//! use rand::Rng;
//!
//! /// `u ↦ 0.9 u`: a solver that loses 10% per step too much.
//! struct Decay;
//! impl Simulator for Decay {
//!     fn step<'t>(&self, u: &StateVars<'t>) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
//!         Ok(vec![u.only()?.mul_scalar(0.9)?])
//!     }
//! }
//! struct Net(UNet);
//! impl Corrector for Net {
//!     fn correction<'t>(&self, p: &Bound<'t, f64>, u: &StateVars<'t>)
//!         -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
//!         Ok(vec![self.0.forward(p, u.only()?)?])
//!     }
//! }
//! let config = UNetConfig { dims: 1, c_in: 1, c_out: 1, widths: vec![4], kernel: 3,
//!     padding: Padding::Periodic, activation: Activation::Identity };
//! let make = |seed: TrainSeed| -> Result<(Net, Params<f64>)> {
//!     let mut params = Params::new();
//!     let net = UNet::new(&mut params, "c", config.clone(), &mut seed.init_rng())?;
//!     Ok((Net(net), params))
//! };
//! // The reference keeps the state: trajectories of constant states.
//! let splits = Splits::generate(DataSeed(1), [4, 2, 2], |_, n, rng| {
//!     Ok((0..n).map(|_| {
//!         let u = ArrayD::from_shape_fn(vec![1, 8], |_| rng.random_range(0.5..1.5));
//!         vec![State::from(u); 9]
//!     }).collect::<Vec<Trajectory>>())
//! })?;
//! let (net, _) = make(TrainSeed(0))?;
//! let hybrid = Hybrid::new(Decay, net);
//! let trainer = Trainer {
//!     budget: Budget { iterations: 60, evaluations_per_iteration: 8 },
//!     learning_rate: 1e-2,
//!     schedule: LrSchedule::Constant,
//!     validate_every: 20,
//!     validation_steps: 8,
//! };
//! let strategy = Strategy::SolverInTheLoop { unroll: 4, schedule: Schedule::Every(2) };
//! let (_, params) = make(TrainSeed(7))?;
//! let trained = trainer.train(&hybrid, params, strategy, &splits.train, &splits.validation,
//!     TrainSeed(7), &|| {})?;
//! let validation = trained.model.validation;
//! let selection = select_best(vec![Candidate::new("sol_4", trained, validation)])?;
//! let model = selection.models.into_iter().next().unwrap();
//! let held_out = splits.held_out().evaluate(model, |m, data| {
//!     rollout(&hybrid, Some(&m.params), data, 8).map(|r| r.mean())
//! })?;
//! let coarse = splits.held_out().evaluate_baseline(|data| Ok(rollout(&hybrid, None, data, 8)?.mean()))?;
//! assert!(held_out.result < 0.5 * coarse);
//! # Ok::<(), LearnError>(())
//! ```
#![warn(missing_docs)]

pub mod cache;
pub mod data;
mod error;
pub mod fit;
pub mod guess;
pub mod hybrid;
pub mod metrics;
pub mod report;
pub mod saved;
mod split;
pub mod state;
pub mod strategy;
pub mod study;
pub mod supervised;
pub mod train;

pub use data::{
    select_best, Candidate, DataSeed, Evaluated, HeldOut, ModelId, Selected, Selection, Split,
    Splits, TrainSeed, Trained,
};
pub use diffphys_tape::Schedule;
pub use error::{LearnError, Result};
pub use hybrid::{frozen, physical_fields, Corrector, Hybrid, Simulator};
pub use metrics::{
    batch_of, relative_l2, relative_l2_fields, rollout, rollout_each, rollout_measured, states_at,
    Metric, Rollout, Trajectory,
};
pub use report::{missed_floors, Figures, Report, RunRecord, RunSeeds, Summary};
pub use saved::{ModelCard, SavedModel};
pub use state::{State, StateVars};
pub use strategy::{standard_normal, Budget, LrSchedule, Strategy};
pub use supervised::{mean_squared_error, Pair, PairSource, SupervisedTrainer, TrainedNet};
pub use train::{Batch, TrainedCorrector, Trainer};
