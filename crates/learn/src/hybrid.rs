//! The solver, the corrector and the hybrid step `solver step, then correction`.

use std::rc::Rc;

use diffphys_nn::{Bound, Params};
use diffphys_tape::{checkpointed_steps, ArrayD, Schedule, StepFn, Tape, TapeError, Var};
use rand::rngs::StdRng;

use crate::state::{State, StateVars};
use crate::{LearnError, Result};

/// A differentiable time step `state → state` of a batch of [`State`]s
/// (every array `[batch, …]`), recorded on the tape, and the same step
/// without a tape.
///
/// A scene implements [`Simulator::step`] from its ops (an advection step, a
/// flow step); [`Simulator::step_plain`] defaults to recording on a throwaway
/// tape, and a scene with a plain function for its step overrides it. The
/// state's per-sample parameters (`state.params`: a viscosity per sample, an
/// inflow profile) are read, never returned: the step gives the new fields.
pub trait Simulator {
    /// How many of the state's last fields are the solver's own auxiliaries
    /// (a pressure carried for incremental splitting, say): carried from step
    /// to step, never compared, corrected or perturbed. Default 0: every field
    /// is physical.
    fn auxiliary_fields(&self) -> usize {
        0
    }

    /// Records one step of every state of the batch `state` on its tape: the
    /// new fields, in the state's order.
    ///
    /// # Errors
    /// Whatever the step's ops return (a state of the wrong shape, say).
    fn step<'t>(&self, state: &StateVars<'t>) -> diffphys_tape::Result<Vec<Var<'t, f64>>>;

    /// One step of the batch `state` without recording anything to keep.
    ///
    /// # Errors
    /// As [`Simulator::step`].
    fn step_plain(&self, state: &State) -> diffphys_tape::Result<Vec<ArrayD<f64>>> {
        let tape = Tape::new();
        Ok(self
            .step(&state.constants(&tape))?
            .iter()
            .map(Var::to_array)
            .collect())
    }

    /// Adds the input noise of [`crate::Strategy::Noise`] to the batch `state`:
    /// by default `sigma · N(0, 1)` to every entry of every physical field, in
    /// order. A simulator whose fields also hold entries that are not physics
    /// (padding, fixed boundary values) overrides it to perturb only the
    /// physical ones.
    fn perturb(&self, state: &mut State, sigma: f64, rng: &mut StdRng) {
        let n = physical_fields(self, state.fields.len());
        for field in &mut state.fields[..n] {
            field.mapv_inplace(|x| x + sigma * crate::strategy::standard_normal(rng));
        }
    }
}

/// The physical fields of a state of `fields` fields under `simulator`.
pub fn physical_fields<S: Simulator + ?Sized>(simulator: &S, fields: usize) -> usize {
    fields.saturating_sub(simulator.auxiliary_fields())
}

/// A network that corrects a state: the hybrid step adds its output to the
/// solver's step, `u ↦ v + c_θ(v)` with `v = step(u)`, on the physical fields.
pub trait Corrector {
    /// Records the corrections `c_θ(state)` of the batch `state` (the solver's
    /// step, its per-sample parameters included) with the parameters `params`
    /// (bound to the state's tape): one per physical field, each of its
    /// field's shape.
    ///
    /// # Errors
    /// Whatever the network's layers return.
    fn correction<'t>(
        &self,
        params: &Bound<'t, f64>,
        state: &StateVars<'t>,
    ) -> diffphys_tape::Result<Vec<Var<'t, f64>>>;
}

/// Parameters as constants of `tape`: evaluation records no gradients.
pub fn frozen<'t>(tape: &'t Tape<f64>, params: &Params<f64>) -> Bound<'t, f64> {
    Bound::from_vars(
        params
            .values()
            .iter()
            .map(|v| tape.constant(v.clone()))
            .collect(),
    )
}

/// A simulator with a corrector: `hybrid step = solver step, then correction`.
/// Cheap to clone (both parts are shared), so unrolls can own a copy.
pub struct Hybrid<S, C> {
    simulator: Rc<S>,
    corrector: Rc<C>,
}

impl<S, C> Clone for Hybrid<S, C> {
    fn clone(&self) -> Self {
        Hybrid {
            simulator: Rc::clone(&self.simulator),
            corrector: Rc::clone(&self.corrector),
        }
    }
}

impl<S: Simulator + 'static, C: Corrector + 'static> Hybrid<S, C> {
    /// The hybrid of `simulator` and `corrector`.
    pub fn new(simulator: S, corrector: C) -> Self {
        Hybrid {
            simulator: Rc::new(simulator),
            corrector: Rc::new(corrector),
        }
    }

    /// The simulator.
    pub fn simulator(&self) -> &S {
        &self.simulator
    }

    /// The corrector.
    pub fn corrector(&self) -> &C {
        &self.corrector
    }

    /// Checks on the batch `probe` that the simulator gives every field and
    /// the corrector one correction of its field's shape per physical field.
    ///
    /// # Errors
    /// [`LearnError::Invalid`] for a state without physical fields or a step
    /// that returns another number of fields; [`LearnError::CorrectorFields`],
    /// [`LearnError::CorrectorShape`]; whatever the step returns.
    pub fn check_shapes(&self, params: &Params<f64>, probe: &State) -> Result<()> {
        if physical_fields(&*self.simulator, probe.fields.len()) == 0 {
            return Err(LearnError::invalid(
                "state",
                format!(
                    "{} fields, {} of them the simulator's auxiliaries: nothing to correct",
                    probe.fields.len(),
                    self.simulator.auxiliary_fields()
                ),
            ));
        }
        let tape = Tape::new();
        let u = probe.constants(&tape);
        let v = self.solver_step(&u)?;
        let c = self.corrector.correction(&frozen(&tape, params), &v)?;
        check_corrections(
            &v.fields,
            &c,
            physical_fields(&*self.simulator, v.fields.len()),
        )
    }

    /// The solver's step of `u`, its parameters carried.
    fn solver_step<'t>(&self, u: &StateVars<'t>) -> diffphys_tape::Result<StateVars<'t>> {
        let fields = self.simulator.step(u)?;
        if let Some(message) = field_count_mismatch(fields.len(), u.fields.len()) {
            return Err(TapeError::invalid("simulator", message));
        }
        Ok(StateVars {
            fields,
            params: u.params.clone(),
        })
    }

    /// Records one hybrid step of the batch `u`; `params = None` is the solver
    /// alone.
    ///
    /// # Errors
    /// [`TapeError::ShapeMismatch`] naming the corrector if a correction does
    /// not have its field's shape, [`TapeError::InvalidArgument`] if the
    /// corrector or the simulator give another number of fields; whatever the
    /// step and the network return.
    pub fn step<'t>(
        &self,
        params: Option<&Bound<'t, f64>>,
        u: &StateVars<'t>,
    ) -> diffphys_tape::Result<StateVars<'t>> {
        let mut v = self.solver_step(u)?;
        let Some(p) = params else { return Ok(v) };
        let n = physical_fields(&*self.simulator, v.fields.len());
        let c = self.corrector.correction(p, &v)?;
        if c.len() != n {
            return Err(TapeError::invalid(
                "corrector",
                format!("{} corrections for {n} physical fields", c.len()),
            ));
        }
        for (f, c) in v.fields.iter_mut().zip(c) {
            if c.shape() != f.shape() {
                return Err(TapeError::shape("corrector", &f.shape(), &c.shape()));
            }
            *f = f.add(c)?;
        }
        Ok(v)
    }

    /// One hybrid step of the batch `u` without a tape to keep (`params = None`
    /// is the solver alone).
    ///
    /// # Errors
    /// As [`Hybrid::check_shapes`], for the step's own fields and corrections.
    pub fn step_plain(&self, params: Option<&Params<f64>>, u: &State) -> Result<State> {
        let fields = self.simulator.step_plain(u)?;
        if let Some(message) = field_count_mismatch(fields.len(), u.fields.len()) {
            return Err(LearnError::invalid("simulator", message));
        }
        let v = State {
            fields,
            params: u.params.clone(),
        };
        let Some(params) = params else { return Ok(v) };
        let tape = Tape::new();
        let vv = v.constants(&tape);
        let c = self.corrector.correction(&frozen(&tape, params), &vv)?;
        let n = physical_fields(&*self.simulator, v.fields.len());
        check_corrections(&vv.fields, &c, n)?;
        let mut fields = v.fields;
        for ((f, fv), c) in fields.iter_mut().zip(&vv.fields).zip(c) {
            *f = fv.add(c)?.to_array();
        }
        Ok(State {
            fields,
            params: v.params,
        })
    }

    /// The unrolled loss `(1/k) Σ_{j=1..k} mse(u_j, targets[j−1])` of `k =
    /// targets.len()` hybrid steps from `s0`, where `mse` is the mean squared
    /// error over every entry of the physical fields together (each field's
    /// mean weighted by its share of the entries) and `targets[j]` holds the
    /// physical fields after step `j + 1`; stored by `schedule` (the gradients
    /// are the same for every schedule; [`Schedule::Full`] keeps every step's
    /// intermediates, [`Schedule::Every`] and [`Schedule::Nested`] recompute
    /// them in the backward sweep).
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] without targets, for targets of another
    /// number of fields than the physical ones, or for an invalid schedule;
    /// whatever the steps return.
    pub fn unrolled_loss<'t>(
        &self,
        tape: &'t Tape<f64>,
        params: &Bound<'t, f64>,
        s0: &StateVars<'t>,
        targets: Rc<Vec<Vec<ArrayD<f64>>>>,
        schedule: Schedule,
    ) -> diffphys_tape::Result<Var<'t, f64>> {
        let k = targets.len();
        if k == 0 {
            return Err(TapeError::invalid("unrolled_loss", "an unroll of 0 steps"));
        }
        let n = s0.fields.len();
        let physical = physical_fields(&*self.simulator, n);
        if let Some(t) = targets.iter().find(|t| t.len() != physical) {
            return Err(TapeError::invalid(
                "unrolled_loss",
                format!(
                    "targets of {} fields for {physical} physical fields",
                    t.len()
                ),
            ));
        }
        let weights = field_weights(&targets[0]);
        let net = params.vars().len();
        let hybrid = self.clone();
        // The loss is carried in the state, so the unroll is one chain of steps
        // that any schedule can checkpoint; the state's per-sample parameters
        // ride with the network's, constant over the steps.
        let step: Rc<StepFn<f64>> = Rc::new(move |tape, j, state, all| {
            let p = Bound::from_vars(all[..net].to_vec());
            let u = StateVars {
                fields: state[..n].to_vec(),
                params: all[net..].to_vec(),
            };
            let mut next = hybrid.step(Some(&p), &u)?.fields;
            let mut loss: Option<Var<'_, f64>> = None;
            for ((f, t), w) in next.iter().zip(&targets[j]).zip(&weights) {
                let e = f
                    .sub(tape.constant(t.clone()))?
                    .powi(2)?
                    .mean()?
                    .mul_scalar(*w)?;
                loss = Some(match loss {
                    None => e,
                    Some(l) => l.add(e)?,
                });
            }
            let loss = loss.ok_or_else(|| TapeError::invalid("unrolled_loss", "no fields"))?;
            next.push(state[n].add(loss)?);
            Ok(next)
        });
        let mut start = s0.fields.clone();
        start.push(tape.scalar(0.0));
        let mut all = params.vars().to_vec();
        all.extend(&s0.params);
        let end = checkpointed_steps(tape, schedule, k, &start, &all, step)?;
        end[n].mul_scalar(1.0 / k as f64)
    }

    /// The gradient of [`Hybrid::unrolled_loss`] from the batch `s0` under
    /// `schedule`: `∂L/∂θ` for every parameter in order, then `∂L/∂s₀`,
    /// flattened (a zero block where a variable got no gradient).
    ///
    /// # Errors
    /// As [`Hybrid::unrolled_loss`] and the backward sweep.
    pub fn unrolled_gradient(
        &self,
        params: &Params<f64>,
        s0: &State,
        targets: Rc<Vec<Vec<ArrayD<f64>>>>,
        schedule: Schedule,
    ) -> Result<Vec<f64>> {
        let tape = Tape::new();
        let p = params.bind(&tape);
        let s = s0.variables(&tape);
        let loss = self.unrolled_loss(&tape, &p, &s, targets, schedule)?;
        let mut wrt = p.vars().to_vec();
        wrt.extend(&s.fields);
        let grads = tape.backward(loss, &wrt)?;
        Ok(wrt
            .iter()
            .flat_map(|v| match grads.get(*v) {
                Some(g) => g.iter().copied().collect::<Vec<_>>(),
                None => vec![0.0; v.shape().iter().product()],
            })
            .collect())
    }
}

/// What is wrong with a step that returned `got` fields for a state of
/// `expected`, if anything.
fn field_count_mismatch(got: usize, expected: usize) -> Option<String> {
    (got != expected).then(|| format!("a step returned {got} fields for a state of {expected}"))
}

/// Each field's share of the entries of `fields` (the weights that make the
/// sum of the fields' means the mean over all their entries).
fn field_weights(fields: &[ArrayD<f64>]) -> Vec<f64> {
    let total: usize = fields.iter().map(ArrayD::len).sum();
    fields
        .iter()
        .map(|f| f.len() as f64 / total.max(1) as f64)
        .collect()
}

/// Refuses corrections that are not one per physical field of `fields` (the
/// first `physical`), each of its field's shape.
fn check_corrections(
    fields: &[Var<'_, f64>],
    corrections: &[Var<'_, f64>],
    physical: usize,
) -> Result<()> {
    if corrections.len() != physical {
        return Err(LearnError::CorrectorFields {
            expected: physical,
            got: corrections.len(),
        });
    }
    for (field, (f, c)) in fields.iter().zip(corrections).enumerate() {
        if c.shape() != f.shape() {
            return Err(LearnError::CorrectorShape {
                field,
                state: f.shape(),
                correction: c.shape(),
            });
        }
    }
    Ok(())
}
