//! The state and the differentiable parameters of a step, without a tape
//! and on one, and what a step reports.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::rc::Rc;

use diffphys_tape::{ArrayD, Real, Tape, Var};
use ndarray::{Array1, Array2, IxDyn};

use super::Scene;
use crate::{FlowError, Result};

/// The state of a flow without a tape.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowState<T> {
    /// `u_x` on the x-faces ([`crate::FlowGrid::shape_x`]).
    pub ux: Array2<T>,
    /// `u_y` on the y-faces ([`crate::FlowGrid::shape_y`]).
    pub uy: Array2<T>,
    /// The pressure `P` at the cell centres (zero at rest; it warm-starts the
    /// next pressure solve, and with [`super::Splitting::Incremental`] enters the step).
    pub pressure: Array2<T>,
    /// Passive scalars at the cell centres.
    pub scalars: Vec<Array2<T>>,
}

impl<T: Real> FlowState<T> {
    /// The fluid at rest, scalars zero.
    pub fn zeros(scene: &Scene) -> Self {
        let g = scene.grid();
        let z = |s: [usize; 2]| Array2::zeros((s[0], s[1]));
        FlowState {
            ux: z(g.shape_x()),
            uy: z(g.shape_y()),
            pressure: z(g.cell_shape()),
            scalars: (0..scene.scalars()).map(|_| z(g.cell_shape())).collect(),
        }
    }

    /// A velocity, the pressure and scalars zero.
    pub fn from_velocity(scene: &Scene, ux: Array2<T>, uy: Array2<T>) -> Self {
        FlowState {
            ux,
            uy,
            ..Self::zeros(scene)
        }
    }
}

/// The state of a flow on a tape.
#[derive(Debug, Clone)]
pub struct FlowVars<'t, T: Real> {
    /// `u_x`.
    pub ux: Var<'t, T>,
    /// `u_y`.
    pub uy: Var<'t, T>,
    /// The pressure `P`.
    pub pressure: Var<'t, T>,
    /// Passive scalars.
    pub scalars: Vec<Var<'t, T>>,
}

impl<'t, T: Real> FlowVars<'t, T> {
    /// The state as constants on `tape`.
    pub fn constants(tape: &'t Tape<T>, s: &FlowState<T>) -> Self {
        FlowVars {
            ux: tape.constant(s.ux.clone().into_dyn()),
            uy: tape.constant(s.uy.clone().into_dyn()),
            pressure: tape.constant(s.pressure.clone().into_dyn()),
            scalars: s
                .scalars
                .iter()
                .map(|a| tape.constant(a.clone().into_dyn()))
                .collect(),
        }
    }

    /// The state with the velocity and scalars as variables (the pressure, a
    /// zero start or a warm start, as a constant).
    pub fn variables(tape: &'t Tape<T>, s: &FlowState<T>) -> Self {
        FlowVars {
            ux: tape.var(s.ux.clone().into_dyn()),
            uy: tape.var(s.uy.clone().into_dyn()),
            pressure: tape.constant(s.pressure.clone().into_dyn()),
            scalars: s
                .scalars
                .iter()
                .map(|a| tape.var(a.clone().into_dyn()))
                .collect(),
        }
    }

    /// `[u_x, u_y, P, scalars…]`, the layout of [`Scene::step_fn`].
    pub fn to_vec(&self) -> Vec<Var<'t, T>> {
        let mut v = vec![self.ux, self.uy, self.pressure];
        v.extend_from_slice(&self.scalars);
        v
    }

    /// From `[u_x, u_y, P, scalars…]`.
    ///
    /// # Errors
    /// [`FlowError::Shape`] for fewer than three entries.
    pub fn from_slice(v: &[Var<'t, T>]) -> Result<Self> {
        if v.len() < 3 {
            return Err(FlowError::shape(
                "flow step",
                "state list",
                &[3],
                &[v.len()],
            ));
        }
        Ok(FlowVars {
            ux: v[0],
            uy: v[1],
            pressure: v[2],
            scalars: v[3..].to_vec(),
        })
    }

    /// The values, copied off the tape.
    ///
    /// # Errors
    /// [`FlowError::Shape`] if a value is not 2D.
    pub fn values(&self) -> Result<FlowState<T>> {
        let two = |v: &Var<'t, T>, what: &str| -> Result<Array2<T>> {
            v.to_array()
                .into_dimensionality()
                .map_err(|_| FlowError::shape("flow step", what, &[0, 0], &v.shape()))
        };
        Ok(FlowState {
            ux: two(&self.ux, "x-velocity")?,
            uy: two(&self.uy, "y-velocity")?,
            pressure: two(&self.pressure, "pressure")?,
            scalars: self
                .scalars
                .iter()
                .map(|s| two(s, "scalar"))
                .collect::<Result<_>>()?,
        })
    }
}

/// The differentiable parameters of a step, without a tape.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowParams<T> {
    /// The kinematic viscosity `ν`.
    pub viscosity: T,
    /// The tangential speed of each side's wall, in the order of [`crate::Side::ALL`]
    /// (read only on moving walls).
    pub wall_speed: Array1<T>,
    /// The inflow profile (empty without an inflow side).
    pub inflow: Array1<T>,
}

/// The differentiable parameters of a step on a tape: `ν` (0-d), the wall
/// speeds (`[4]`), the inflow profile.
#[derive(Debug, Clone, Copy)]
pub struct ParamVars<'t, T: Real> {
    /// `ν`.
    pub viscosity: Var<'t, T>,
    /// The four wall speeds.
    pub wall_speed: Var<'t, T>,
    /// The inflow profile.
    pub inflow: Var<'t, T>,
}

impl<'t, T: Real> ParamVars<'t, T> {
    /// The parameters as variables on `tape` (all of them get gradients).
    pub fn variables(tape: &'t Tape<T>, p: &FlowParams<T>) -> Self {
        ParamVars {
            viscosity: tape.var(ArrayD::from_elem(IxDyn(&[]), p.viscosity)),
            wall_speed: tape.var(p.wall_speed.clone().into_dyn()),
            inflow: tape.var(p.inflow.clone().into_dyn()),
        }
    }

    /// The parameters as constants on `tape`.
    pub fn constants(tape: &'t Tape<T>, p: &FlowParams<T>) -> Self {
        ParamVars {
            viscosity: tape.constant(ArrayD::from_elem(IxDyn(&[]), p.viscosity)),
            wall_speed: tape.constant(p.wall_speed.clone().into_dyn()),
            inflow: tape.constant(p.inflow.clone().into_dyn()),
        }
    }

    /// `[ν, wall_speed, inflow]`, the layout of [`Scene::step_fn`].
    pub fn to_vec(&self) -> Vec<Var<'t, T>> {
        vec![self.viscosity, self.wall_speed, self.inflow]
    }

    /// From `[ν, wall_speed, inflow]`.
    ///
    /// # Errors
    /// [`FlowError::Shape`] for a list of another length.
    pub fn from_slice(v: &[Var<'t, T>]) -> Result<Self> {
        if v.len() != 3 {
            return Err(FlowError::shape(
                "flow step",
                "parameter list",
                &[3],
                &[v.len()],
            ));
        }
        Ok(ParamVars {
            viscosity: v[0],
            wall_speed: v[1],
            inflow: v[2],
        })
    }
}

/// What a step did.
#[derive(Debug, Clone, PartialEq)]
pub struct StepInfo {
    /// Substeps taken (1 unless substepping was needed).
    pub substeps: usize,
    /// The Courant number `max |u| dt/h` of the state at the start, for the
    /// full `dt`.
    pub courant: f64,
    /// CG iterations of each pressure solve (0 for the direct solver).
    pub pressure_iterations: Vec<usize>,
    /// The force `[F_x, F_y]` of the flow on the immersed body over the step
    /// by the momentum its forcing exchanges (zero without one):
    /// `F = −(1/dt) Σ_substeps Σ_forced (u'_f − u*_f) dx dy`, `u*` the velocity
    /// the forcing is given, `u'` its output. With [`crate::immersed::Interior::Forced`]
    /// that is the whole exchange with the body (for a body at rest, whose
    /// inside holds no momentum after the forcing); with
    /// [`crate::immersed::Interior::Solid`] the staircase's pressure and
    /// viscous exchange come on top. Each call of a step reports its own; over
    /// a checkpointed rollout, whose backward sweep calls steps again, read
    /// them from a [`StepLog`] ([`Scene::rollout_logged`]), which keeps one
    /// report per step.
    pub immersed_force: [f64; 2],
}

/// The reports of a rollout's steps, one per step index: a step that a
/// checkpointed segment recomputes in the backward sweep replaces its own
/// report instead of adding a second, so the sums over the rollout
/// ([`StepLog::immersed_impulse`], [`StepLog::pressure_iterations`]) count
/// each step once however often it ran. Shared by its clones.
#[derive(Debug, Clone, Default)]
pub struct StepLog(Rc<RefCell<BTreeMap<usize, StepInfo>>>);

impl StepLog {
    /// Empty.
    pub fn new() -> Self {
        Self::default()
    }

    /// Records step `k`'s report, replacing an earlier one of the same step.
    pub fn record(&self, k: usize, info: StepInfo) {
        self.0.borrow_mut().insert(k, info);
    }

    /// How many steps have a report.
    pub fn len(&self) -> usize {
        self.0.borrow().len()
    }

    /// Whether no step has a report.
    pub fn is_empty(&self) -> bool {
        self.0.borrow().is_empty()
    }

    /// The reports in step order.
    pub fn infos(&self) -> Vec<StepInfo> {
        self.0.borrow().values().cloned().collect()
    }

    /// `Σ_k dt F_k`: the momentum the immersed body took from the flow over
    /// the logged steps (each step's [`StepInfo::immersed_force`] times `dt`).
    pub fn immersed_impulse(&self, dt: f64) -> [f64; 2] {
        self.0.borrow().values().fold([0.0; 2], |a, i| {
            [
                a[0] + dt * i.immersed_force[0],
                a[1] + dt * i.immersed_force[1],
            ]
        })
    }

    /// The CG iterations of every pressure solve of the logged steps, in order.
    pub fn pressure_iterations(&self) -> Vec<usize> {
        self.0
            .borrow()
            .values()
            .flat_map(|i| i.pressure_iterations.iter().copied())
            .collect()
    }
}
