//! # diffphys-hybrid
//!
//! The pieces a hybrid flow solver (a coarse flow solver plus a corrector
//! network trained through it, `diffphys-learn`) needs beyond the two
//! libraries it joins:
//!
//! - [`FlowSimulator`]: a [`diffphys_flow::Scene`] as the learning library's
//!   [`diffphys_learn::Simulator`]. Its state is the scene's fields
//!   ([`diffphys_flow::Scene::batch_fields`]: `u_x`, `u_y`, and the pressure
//!   when the scheme carries it, an auxiliary field) with each sample's
//!   viscosity as its parameter, so one batch mixes Reynolds numbers; input
//!   noise lands on the [`free_faces`] only. It also measures what no
//!   corrector can remove ([`FlowSimulator::pinned_face_error`]) and the
//!   noise scale of a training set ([`FlowSimulator::one_step_rms`]).
//! - [`LatticeNet`]: a residual convolutional corrector on the face lattice
//!   `[2, nx + 1, ny + 1]` (both velocity components as channels, plus one
//!   channel coding each sample's viscosity), its corrections masked to the
//!   free faces and its head starting at zero, so the hybrid starts as the
//!   solver.
//! - Reference trajectories ([`mod@reference`]): a finer solver's states
//!   restricted to the coarse grid, recorded after a skipped transient, in a
//!   cache form; a hybrid's rollouts scored against one.
//! - Speed against accuracy ([`speed`]): the corrected coarse solver and
//!   uncorrected finer ones from the same starts against the same reference,
//!   timed per coarse step.
//! - A body in a channel ([`wake`]): the wake scene family's solvers at
//!   every resolution, its cached reference, saved correctors re-evaluated
//!   at any Re, the reference's convergence check and the speed study.
//! - Flow metrics of a rollout ([`metrics`]): the error of the velocity's
//!   deviation from a free stream and of the vorticity, as
//!   [`diffphys_learn::Metric`]s read them.
//!
//! ```
//! use diffphys_flow::{FlowState, Scene, Sides};
//! use diffphys_hybrid::FlowSimulator;
//! use diffphys_learn::{Simulator, State};
//! use ndarray::Array2;
//!
//! let scene = Scene::builder(8, 8, [1.0, 1.0]).sides(Sides::periodic()).dt(0.05).build()?;
//! let sim = FlowSimulator::new(scene.clone());
//! let g = scene.grid();
//! let state = FlowState::from_velocity(&scene, Array2::from_elem(g.shape_x(), 0.5), Array2::zeros(g.shape_y()));
//! // Two samples at two viscosities, one batch.
//! let batch = State::stack(&[&sim.sample(&state, 1e-2), &sim.sample(&state, 1e-3)])?;
//! let next = sim.step_plain(&batch)?;
//! assert_eq!(next[0].shape(), &[2, 8, 8]);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![warn(missing_docs)]

pub mod convergence;
mod corrector;
pub mod metrics;
pub mod reference;
mod simulator;
pub mod speed;
pub mod study;
pub mod wake;

pub use corrector::{LatticeNet, NetSize, ParamCode};
pub use simulator::{free_faces, sample, FlowSimulator};

use diffphys_flow::FlowError;
use diffphys_learn::LearnError;
use diffphys_nn::NnError;
use diffphys_tape::TapeError;

/// Everything the hybrid pieces refuse.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HybridError {
    /// A corrector size label that is not `wXbY` with a positive width.
    #[error("not a corrector size wXbY (width X > 0, Y residual blocks): {label:?}")]
    Size {
        /// What was given.
        label: String,
    },
    /// A trajectory too short for what was asked of it.
    #[error("{what}: {message}")]
    Trajectory {
        /// The measurement.
        what: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The reference carries flow on faces the coarse solver pins although
    /// the body was built so that it cannot.
    #[error("the reference carries flow on faces the coarse solver pins (relative {error:.3e} at Re {re}) although the {body} body was built to rule that out")]
    PinnedFaces {
        /// The body.
        body: &'static str,
        /// The Reynolds number.
        re: f64,
        /// The pinned-face error.
        error: f64,
    },
    /// A Reynolds number outside the scene's range (or not finite).
    #[error("Reynolds number {re} is outside the scene's range [{}, {}]", range[0], range[1])]
    ReOutOfRange {
        /// What was asked for.
        re: f64,
        /// The range.
        range: [f64; 2],
    },
    /// A bad command-line argument.
    #[error("{option}: {message}")]
    Argument {
        /// The option.
        option: String,
        /// What is wrong.
        message: String,
    },
    /// A setting the scene cannot honour.
    #[error("{what}: {message}")]
    Setting {
        /// The setting.
        what: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The learning library refused.
    #[error(transparent)]
    Learn(#[from] LearnError),
    /// The flow solver refused.
    #[error(transparent)]
    Flow(#[from] FlowError),
    /// A network layer refused.
    #[error(transparent)]
    Nn(#[from] NnError),
    /// A tape op refused.
    #[error(transparent)]
    Tape(#[from] TapeError),
}

/// The crate's result type.
pub type Result<T> = std::result::Result<T, HybridError>;
