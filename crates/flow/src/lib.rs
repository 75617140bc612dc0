//! # diffphys-flow
//!
//! A differentiable 2D incompressible Navier–Stokes step on a staggered (MAC)
//! grid, on the diffphys tape. Each physical operator lives in its own module,
//! as a pair of plain functions (forward, vector–Jacobian product) and an
//! [`Op`] adapter:
//!
//! | module | operator |
//! | --- | --- |
//! | [`grid`] | cells, faces, array layout |
//! | [`sides`] | the side vocabulary: [`Side`], the [`SideCondition`] trait and its shipped types, [`Boundary`], [`Sides`] |
//! | [`boundaries`] | obstacles, the condition of every face ([`Faces`]), [`boundaries::enforce_boundaries`] |
//! | [`advection`] | semi-Lagrangian and MacCormack self-advection, passive scalars |
//! | [`diffusion`] | explicit and implicit viscosity ([`diffusion::Diffusion`]) |
//! | [`pressure`] | projection with the obstacle, implicit adjoint, warm start ([`pressure::PressureSystem`]) |
//! | [`forcing`] | Boussinesq buoyancy |
//! | [`immersed`] | a circle as a direct-forcing immersed boundary on the faces ([`immersed::ImmersedCircle`]) |
//! | [`diagnostics`] | divergence, vorticity, drag and lift |
//! | [`step`] | the [`Scene`] and the step composed of the above |
//! | [`batch`] | batches of states as fields `[batch, …]`, a viscosity per sample (a learning library's state) |
//! | [`restrict`] | a state restricted to a coarser grid: face averages, cell averages |
//! | [`validation`] | the validation flows against their references: Taylor–Green, the cavity (Ghia 1982), the DFG cylinder (Schäfer–Turek 1996) |
//!
//! The operators take what they act on (the grid, its [`Faces`], an
//! assembled operator, the fields, `ν`, `dt`), never a scene; the [`Scene`]
//! owns those pieces ([`Scene::faces`], [`Scene::diffusion`],
//! [`Scene::pressure_system`], [`Scene::force_weights`]) and composes the step.
//! Inside the crate the modules depend downwards only: grid and sides at the
//! bottom; boundaries, buffers, sparse, spectral and the staggered `D` and `G`;
//! the operators; the step; batch, restrict and validation on top.
//!
//! A scene is described once; a rollout is a loop of [`Scene::step`] on a tape
//! (or [`Scene::rollout`], checkpointed), and the gradient of any loss of the
//! final state with respect to the initial state, the viscosity, the wall
//! speeds or the inflow profile is one `tape.backward`:
//!
//! ```
//! use diffphys_flow::{Obstacle, Scene, Sides, FlowState, FlowVars, ParamVars};
//! use diffphys_tape::{Schedule, Tape};
//!
//! // A channel 2 × 1 with a cylinder, parabolic inflow, outflow on the right.
//! let scene = Scene::builder(32, 16, [2.0, 1.0])
//!     .sides(Sides::channel())
//!     .obstacle(Obstacle::cylinder([0.5, 0.5], 0.15))
//!     .parabolic_inflow(1.0)
//!     .viscosity(0.01)
//!     .dt(0.02)
//!     .build()?;
//!
//! let tape = Tape::<f64>::new();
//! let state = FlowVars::constants(&tape, &FlowState::zeros(&scene));
//! let params = ParamVars::variables(&tape, &scene.params());
//! let end = scene.rollout(&tape, Schedule::Every(5), 10, &state, &params)?;
//!
//! // Gradient of the kinetic energy after 10 steps w.r.t. the inflow and ν.
//! let energy = end.ux.mul(end.ux)?.sum()?.add(end.uy.mul(end.uy)?.sum()?)?;
//! let grads = tape.backward(energy, &[params.inflow, params.viscosity])?;
//! let d_inflow = grads.get(params.inflow).unwrap();
//! assert_eq!(d_inflow.len(), 16);
//! assert!(d_inflow.iter().any(|g| *g != 0.0));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![warn(missing_docs)]

pub mod advection;
pub mod batch;
pub mod boundaries;
mod buffers;
pub mod diagnostics;
pub mod diffusion;
mod error;
pub mod forcing;
pub mod grid;
pub mod immersed;
pub mod pressure;
pub mod restrict;
pub mod sides;
mod sparse;
mod spectral;
mod staggered;
pub mod step;
pub mod validation;

pub use advection::Advection;
pub use boundaries::{Faces, Obstacle};
pub use diffusion::ViscosityMode;
pub use error::{FlowError, Result};
pub use forcing::{Buoyancy, Forced, Forcing};
pub use grid::{FlowGrid, Lattice};
pub use immersed::{Circle, ForcingScheme, ImmersedCircle, Interior};
pub use pressure::PressureSolver;
pub use restrict::{restrict_pressure, restrict_velocity};
pub use sides::{Boundary, Side, SideCondition, Sides};
pub use step::{
    Exec, FlowParams, FlowState, FlowVars, ParamVars, Scene, SceneBuilder, Settings, Splitting,
    StepInfo, StepLog,
};
pub use validation::TaylorGreen;

use diffphys_tape::{Op, Real, Tape, Var};

/// Records a (multi-output) op: the one place that names the tape's recording
/// call.
pub(crate) fn record<'t, T: Real, O: Op<T> + 'static>(
    tape: &'t Tape<T>,
    op: O,
    inputs: &[Var<'t, T>],
) -> diffphys_tape::Result<Vec<Var<'t, T>>> {
    tape.apply_multi(op, inputs)
}
