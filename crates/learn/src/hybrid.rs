//! The solver, the corrector and the hybrid step `solver step, then correction`.

use std::rc::Rc;

use diffphys_nn::{Bound, Params};
use diffphys_tape::{checkpointed_steps, ArrayD, Schedule, StepFn, Tape, TapeError, Var};
use rand::rngs::StdRng;

use crate::{LearnError, Result};

/// A differentiable time step `state → state` of a batch of states
/// `[batch, …]`, recorded on the tape, and the same step without a tape.
///
/// A scene implements [`Simulator::step`] from its ops (an advection step, a
/// flow step); [`Simulator::step_plain`] defaults to recording on a throwaway
/// tape, and a scene with a plain function for its step overrides it.
pub trait Simulator {
    /// Records one step of every state of the batch `state` on its tape.
    ///
    /// # Errors
    /// Whatever the step's ops return (a state of the wrong shape, say).
    fn step<'t>(&self, state: Var<'t, f64>) -> diffphys_tape::Result<Var<'t, f64>>;

    /// One step of the batch `state` without recording anything to keep.
    ///
    /// # Errors
    /// As [`Simulator::step`].
    fn step_plain(&self, state: &ArrayD<f64>) -> diffphys_tape::Result<ArrayD<f64>> {
        let tape = Tape::new();
        Ok(self.step(tape.constant(state.clone()))?.to_array())
    }

    /// Adds the input noise of [`crate::Strategy::Noise`] to the batch `state`:
    /// by default `sigma · N(0, 1)` to every entry, in order. A simulator
    /// whose state also holds entries that are not physics (a parameter such
    /// as the viscosity, padding, fixed boundary values) overrides it to
    /// perturb only the physical ones.
    fn perturb(&self, state: &mut ArrayD<f64>, sigma: f64, rng: &mut StdRng) {
        state.mapv_inplace(|x| x + sigma * crate::strategy::standard_normal(rng));
    }
}

/// A network that corrects a state: the hybrid step adds its output to the
/// solver's step, `u ↦ v + c_θ(v)` with `v = step(u)`.
pub trait Corrector {
    /// Records the correction `c_θ(state)` of the batch `state` with the
    /// parameters `params` (bound to the state's tape); it must have the state's
    /// shape.
    ///
    /// # Errors
    /// Whatever the network's layers return.
    fn correction<'t>(
        &self,
        params: &Bound<'t, f64>,
        state: Var<'t, f64>,
    ) -> diffphys_tape::Result<Var<'t, f64>>;
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

    /// Checks on the batch `probe` that the corrector's output has the state's
    /// shape.
    ///
    /// # Errors
    /// [`LearnError::CorrectorShape`] if it does not; whatever the step returns.
    pub fn check_shapes(&self, params: &Params<f64>, probe: &ArrayD<f64>) -> Result<()> {
        let tape = Tape::new();
        let v = self.simulator.step(tape.constant(probe.clone()))?;
        let c = self.corrector.correction(&frozen(&tape, params), v)?;
        if c.shape() != v.shape() {
            return Err(LearnError::CorrectorShape {
                state: v.shape(),
                correction: c.shape(),
            });
        }
        Ok(())
    }

    /// Records one hybrid step of the batch `u`; `params = None` is the solver
    /// alone.
    ///
    /// # Errors
    /// [`TapeError::ShapeMismatch`] naming the corrector if its output does not
    /// have the state's shape; whatever the step and the network return.
    pub fn step<'t>(
        &self,
        params: Option<&Bound<'t, f64>>,
        u: Var<'t, f64>,
    ) -> diffphys_tape::Result<Var<'t, f64>> {
        let v = self.simulator.step(u)?;
        let Some(p) = params else { return Ok(v) };
        let c = self.corrector.correction(p, v)?;
        if c.shape() != v.shape() {
            return Err(TapeError::shape("corrector", &v.shape(), &c.shape()));
        }
        v.add(c)
    }

    /// One hybrid step of the batch `u` without a tape to keep (`params = None`
    /// is the solver alone).
    ///
    /// # Errors
    /// As [`Hybrid::step`].
    pub fn step_plain(&self, params: Option<&Params<f64>>, u: &ArrayD<f64>) -> Result<ArrayD<f64>> {
        let Some(params) = params else {
            return Ok(self.simulator.step_plain(u)?);
        };
        let v = self.simulator.step_plain(u)?;
        let tape = Tape::new();
        let vv = tape.constant(v);
        let c = self.corrector.correction(&frozen(&tape, params), vv)?;
        if c.shape() != vv.shape() {
            return Err(LearnError::CorrectorShape {
                state: vv.shape(),
                correction: c.shape(),
            });
        }
        Ok(vv.add(c)?.to_array())
    }

    /// The unrolled loss `(1/k) Σ_{j=1..k} mean((u_j − targets[j−1])²)` of `k =
    /// targets.len()` hybrid steps from `s0`, stored by `schedule` (the gradients
    /// are the same for every schedule; [`Schedule::Full`] keeps every step's
    /// intermediates, [`Schedule::Every`] and [`Schedule::Nested`] recompute
    /// them in the backward sweep).
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] without targets or for an invalid
    /// schedule; whatever the steps return.
    pub fn unrolled_loss<'t>(
        &self,
        tape: &'t Tape<f64>,
        params: &Bound<'t, f64>,
        s0: Var<'t, f64>,
        targets: Rc<Vec<ArrayD<f64>>>,
        schedule: Schedule,
    ) -> diffphys_tape::Result<Var<'t, f64>> {
        let k = targets.len();
        if k == 0 {
            return Err(TapeError::invalid("unrolled_loss", "an unroll of 0 steps"));
        }
        let hybrid = self.clone();
        // The loss is carried in the state, so the unroll is one chain of steps
        // that any schedule can checkpoint.
        let step: Rc<StepFn<f64>> = Rc::new(move |tape, j, state, params| {
            let p = Bound::from_vars(params.to_vec());
            let u = hybrid.step(Some(&p), state[0])?;
            let l = u.sub(tape.constant(targets[j].clone()))?.powi(2)?.mean()?;
            Ok(vec![u, state[1].add(l)?])
        });
        let acc = tape.scalar(0.0);
        let end = checkpointed_steps(tape, schedule, k, &[s0, acc], params.vars(), step)?;
        end[1].mul_scalar(1.0 / k as f64)
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
        s0: &ArrayD<f64>,
        targets: Rc<Vec<ArrayD<f64>>>,
        schedule: Schedule,
    ) -> Result<Vec<f64>> {
        let tape = Tape::new();
        let p = params.bind(&tape);
        let s = tape.var(s0.clone());
        let loss = self.unrolled_loss(&tape, &p, s, targets, schedule)?;
        let mut wrt = p.vars().to_vec();
        wrt.push(s);
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
