//! Batches of flow states as fields `[batch, …]`, each sample at its own
//! viscosity: the state a learning library steps (diffphys-learn's
//! `Simulator` over a state of several fields with per-sample parameters).
//!
//! **Layout.** A batch is [`Scene::batch_fields`] fields: `u_x`
//! `[batch, nx + 1, ny]`, `u_y` `[batch, nx, ny + 1]` and, when the scene
//! carries its pressure from step to step ([`Splitting::Incremental`], whose
//! predictor subtracts the previous pressure's gradient), the pressure
//! `[batch, nx, ny]`. Under [`Splitting::Plain`] the state's pressure is only
//! the warm start of the next solve, so it is not carried: every step starts
//! from `P = 0`. The viscosity is `[batch]`, one per sample, so a batch mixes
//! Reynolds numbers; the inflow profile and the wall speeds are the scene's.
//! Scalars are not carried (scenes with scalars are refused).
//!
//! **Formula.** Sample `b` of [`Scene::step_batch`] is [`Scene::step`] of
//! sample `b` at `ν_b`: `(u_b, P_b) ↦ step(u_b, P_b; ν_b)`.
//!
//! **Adjoint.** The samples do not interact, so the batch's vector–Jacobian
//! product is each sample's, `(ū_b, P̄_b, ν̄_b) = step_vjp_b(ū'_b, P̄'_b)`: the
//! step is recorded per sample through the tape's `slice`, `reshape` and
//! `concat` (whose adjoints scatter back into the batch), so gradients reach
//! every field and each sample's viscosity exactly as through [`Scene::step`].

use diffphys_tape::{ArrayD, Real, Var};
use ndarray::{ArrayViewD, Axis};

use crate::step::Splitting;
use crate::{FlowError, FlowParams, FlowState, FlowVars, ParamVars, Result, Scene};

const STEP: &str = "batched flow step";

impl Scene {
    /// The fields of a batched state: 2 (`u_x`, `u_y`) or, with
    /// [`Splitting::Incremental`], 3 (and the pressure). See the
    /// [module docs](crate::batch).
    pub fn batch_fields(&self) -> usize {
        if self.settings().splitting == Splitting::Incremental {
            3
        } else {
            2
        }
    }

    /// The shapes of one sample's fields (without the batch axis).
    pub fn sample_shapes(&self) -> Vec<[usize; 2]> {
        let g = self.grid();
        let mut shapes = vec![g.shape_x(), g.shape_y()];
        if self.batch_fields() == 3 {
            shapes.push(g.cell_shape());
        }
        shapes
    }

    /// The fields of `state` as one sample (no batch axis): `u_x`, `u_y` and,
    /// if the scene carries it, the pressure.
    pub fn sample_of<T: Real>(&self, state: &FlowState<T>) -> Vec<ArrayD<T>> {
        let mut fields = vec![state.ux.clone().into_dyn(), state.uy.clone().into_dyn()];
        if self.batch_fields() == 3 {
            fields.push(state.pressure.clone().into_dyn());
        }
        fields
    }

    /// The state of one sample's fields (the pressure zero if not carried).
    ///
    /// # Errors
    /// [`FlowError::Shape`] for fields of another number or shape.
    pub fn state_of<T: Real>(&self, fields: &[ArrayViewD<'_, T>]) -> Result<FlowState<T>> {
        let shapes = self.sample_shapes();
        if fields.len() != shapes.len() {
            return Err(FlowError::shape(
                STEP,
                "fields of a sample",
                &[shapes.len()],
                &[fields.len()],
            ));
        }
        let field = |i: usize, name: &str| {
            fields[i]
                .to_owned()
                .into_shape_with_order((shapes[i][0], shapes[i][1]))
                .map_err(|_| FlowError::shape(STEP, name, &shapes[i], fields[i].shape()))
        };
        let mut state = FlowState::from_velocity(self, field(0, "u_x")?, field(1, "u_y")?);
        if shapes.len() == 3 {
            state.pressure = field(2, "pressure")?;
        }
        Ok(state)
    }

    /// The batch size of fields of `shapes` with viscosities of `viscosity`,
    /// after checking every shape.
    fn batch_size(&self, shapes: &[Vec<usize>], viscosity: &[usize]) -> Result<usize> {
        if self.scalars() != 0 {
            return Err(FlowError::scene(
                "scalars",
                "batched states carry no passive scalars",
            ));
        }
        let expected = self.sample_shapes();
        if shapes.len() != expected.len() {
            return Err(FlowError::shape(
                STEP,
                "fields",
                &[expected.len()],
                &[shapes.len()],
            ));
        }
        let batch = viscosity.first().copied().unwrap_or(0);
        if viscosity.len() != 1 || batch == 0 {
            return Err(FlowError::shape(
                STEP,
                "viscosity",
                &[batch.max(1)],
                viscosity,
            ));
        }
        let names = ["u_x", "u_y", "pressure"];
        for ((shape, e), name) in shapes.iter().zip(&expected).zip(names) {
            if shape[..] != [batch, e[0], e[1]] {
                return Err(FlowError::shape(STEP, name, &[batch, e[0], e[1]], shape));
            }
        }
        Ok(batch)
    }

    /// One step of every sample of the batch `fields` at its viscosity
    /// `viscosity[b]`, recorded on their tape (see the
    /// [module docs](crate::batch) for the layout, formula and adjoint).
    ///
    /// # Errors
    /// [`FlowError::Shape`] for fields of another number or shape, or
    /// viscosities of another batch; [`FlowError::InvalidScene`] for a scene
    /// with scalars; whatever [`Scene::step`] returns.
    pub fn step_batch<'t, T: Real>(
        &self,
        fields: &[Var<'t, T>],
        viscosity: Var<'t, T>,
    ) -> Result<Vec<Var<'t, T>>> {
        let shapes: Vec<_> = fields.iter().map(Var::shape).collect();
        let batch = self.batch_size(&shapes, &viscosity.shape())?;
        let tape = viscosity.tape();
        let params = ParamVars::constants(tape, &self.params::<T>());
        let zeros = tape.constant(ArrayD::zeros(self.grid().cell_shape().to_vec()));
        let t = FlowError::from_tape;
        let mut out: Vec<Vec<Var<'t, T>>> = vec![Vec::with_capacity(batch); fields.len()];
        for b in 0..batch {
            let one = |f: Var<'t, T>| f.slice(0, b, b + 1)?.reshape(&f.shape()[1..]);
            let vars = FlowVars {
                ux: one(fields[0]).map_err(t)?,
                uy: one(fields[1]).map_err(t)?,
                pressure: match fields.get(2) {
                    Some(&p) => one(p).map_err(t)?,
                    None => zeros,
                },
                scalars: Vec::new(),
            };
            let p = ParamVars {
                viscosity: viscosity
                    .slice(0, b, b + 1)
                    .and_then(|v| v.reshape(&[]))
                    .map_err(t)?,
                ..params
            };
            let (next, _) = self.step(tape, &vars, &p)?;
            let mut next = vec![next.ux, next.uy, next.pressure];
            next.truncate(fields.len());
            for (o, v) in out.iter_mut().zip(next) {
                let mut shape = vec![1];
                shape.extend(v.shape());
                o.push(v.reshape(&shape).map_err(t)?);
            }
        }
        out.iter().map(|o| Var::concat(o, 0).map_err(t)).collect()
    }

    /// [`Scene::step_batch`] without a tape: [`Scene::forward`] of every
    /// sample.
    ///
    /// # Errors
    /// As [`Scene::step_batch`].
    pub fn forward_batch<T: Real>(
        &self,
        fields: &[ArrayViewD<'_, T>],
        viscosity: ArrayViewD<'_, T>,
    ) -> Result<Vec<ArrayD<T>>> {
        let shapes: Vec<_> = fields.iter().map(|f| f.shape().to_vec()).collect();
        let batch = self.batch_size(&shapes, viscosity.shape())?;
        let params = self.params::<T>();
        let mut out: Vec<Vec<ArrayD<T>>> = vec![Vec::with_capacity(batch); fields.len()];
        for b in 0..batch {
            let sample: Vec<_> = fields.iter().map(|f| f.index_axis(Axis(0), b)).collect();
            let p = FlowParams {
                viscosity: viscosity[[b]],
                ..params.clone()
            };
            let (next, _) = self.forward(&self.state_of(&sample)?, &p)?;
            for (o, v) in out.iter_mut().zip(self.sample_of(&next)) {
                o.push(v);
            }
        }
        out.iter()
            .map(|o| {
                let views: Vec<_> = o.iter().map(|a| a.view()).collect();
                ndarray::stack(Axis(0), &views)
                    .map_err(|e| FlowError::parameter(STEP, "batch", e.to_string()))
            })
            .collect()
    }
}
