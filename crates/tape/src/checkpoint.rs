//! Checkpointing: record a stretch of computation as one node that keeps only its
//! inputs and outputs, and recompute the stretch during the backward sweep.
//!
//! A long unroll (a solver stepped 1024 times, say) on a plain tape keeps every
//! intermediate of every step. With checkpoints every `m` steps the tape keeps
//! only the state at every `m`-th step; the backward sweep of each segment
//! recomputes that segment's states from its checkpoint, then walks back through
//! it one step at a time, recording one step at a time on a scratch tape. Peak
//! memory falls from `N` steps' intermediates to `N/m` states plus `m` states plus
//! one step's intermediates (least near `m = √N`), for about two extra forward
//! passes. [`Schedule::Nested`] applies the same idea recursively, for a
//! logarithmic number of stored states at one more forward pass per level.
//!
//! The step is any closure of recorded ops, `step(tape, k, state, params) →
//! state`; parameters (a network's weights, a viscosity) are inputs of every
//! segment, so their gradients sum over all steps as on the full tape. An error
//! of the step, in the forward pass or in a recomputation, and a non-finite
//! gradient in the backward sweep are reported with the step's index.
//!
//! [`Tape::checkpoint`] is the general form: any closure over any inputs as one
//! recomputed node.
//!
//! # References
//! A. Griewank and A. Walther, *Algorithm 799: revolve*, ACM TOMS 26 (2000)
//! 19–45; T. Chen et al., *Training deep nets with sublinear memory cost*,
//! arXiv:1604.06174 (2016).

use std::rc::Rc;

use ndarray::{ArrayD, ArrayViewD};

use crate::pool::BufferPool;
use crate::{BackwardArgs, Op, Real, Result, Tape, TapeError, Var};

/// A stretch of recorded computation: outputs from inputs on the tape it is given.
pub type SegmentFn<T> = dyn for<'s> Fn(&'s Tape<T>, &[Var<'s, T>]) -> Result<Vec<Var<'s, T>>>;

/// One step of an unroll: `step(tape, k, state, params)` returns the state after
/// step `k`, with as many arrays as `state`.
pub type StepFn<T> =
    dyn for<'s> Fn(&'s Tape<T>, usize, &[Var<'s, T>], &[Var<'s, T>]) -> Result<Vec<Var<'s, T>>>;

/// How [`checkpointed_steps`] stores an unroll.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Schedule {
    /// Every step on the tape (no checkpointing): the reference.
    Full,
    /// A checkpoint every `m` steps.
    Every(usize),
    /// Segments split into `branches` checkpointed sub-segments, recursively,
    /// down to segments of at most `branches` steps: about
    /// `branches · log_branches(N)` stored states, one extra forward per level.
    Nested {
        /// Sub-segments per segment (at least 2).
        branches: usize,
    },
}

/// Wraps an error of step `k` so that it names the step.
fn at_step(k: usize, pass: &'static str) -> impl FnOnce(TapeError) -> TapeError {
    move |e| TapeError::op(&format!("checkpointed step {k} ({pass})"), e)
}

fn arrays<T: Real>(vars: &[Var<'_, T>]) -> Vec<ArrayD<T>> {
    vars.iter().map(|v| v.to_array()).collect()
}

/// Records `<outputs, seeds>` (seeds where a gradient arrived) as a scalar on
/// `tape`, so that one backward sweep gives the vector–Jacobian product of all
/// outputs at once; `None` if no gradient arrived.
fn seeded_sum<'s, T: Real>(
    tape: &'s Tape<T>,
    outputs: &[Var<'s, T>],
    seeds: &[Option<ArrayD<T>>],
) -> Result<Option<Var<'s, T>>> {
    let mut total: Option<Var<'s, T>> = None;
    for (out, seed) in outputs.iter().zip(seeds) {
        if let Some(seed) = seed {
            let term = out.dot(tape.constant(seed.clone()))?;
            total = Some(match total {
                Some(t) => t.add(term)?,
                None => term,
            });
        }
    }
    Ok(total)
}

fn add_into<T: Real>(acc: &mut Option<ArrayD<T>>, g: Option<&ArrayD<T>>) {
    if let Some(g) = g {
        match acc {
            Some(a) => *a += g,
            None => *acc = Some(g.clone()),
        }
    }
}

/// A closure recorded as one node (see [`Tape::checkpoint`]).
struct Checkpoint<T: Real> {
    name: String,
    f: Rc<SegmentFn<T>>,
    check_finite: bool,
}

impl<T: Real> Checkpoint<T> {
    fn scratch(&self) -> Tape<T> {
        scratch_tape(self.check_finite)
    }
}

/// A scratch tape with a buffer pool of its own, freed with it. `Tape::new()`
/// would share the pool of the tape whose op is running, which keeps what every
/// dropped scratch tape recycles (up to its limit) and so would hold every
/// recomputed step's buffers: the memory the checkpoint exists to save.
fn scratch_tape<T: Real>(check_finite: bool) -> Tape<T> {
    let tape = Tape::with_pool(&BufferPool::new());
    tape.set_check_finite(check_finite);
    tape
}

impl<T: Real> Op<T> for Checkpoint<T> {
    fn name(&self) -> &str {
        &self.name
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        let tape = self.scratch();
        let vars: Vec<_> = inputs.iter().map(|x| tape.constant(x.to_owned())).collect();
        Ok(arrays(&(self.f)(&tape, &vars)?))
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let tape = self.scratch();
        let vars: Vec<_> = args
            .inputs
            .iter()
            .enumerate()
            .map(|(i, x)| {
                if args.needs(i) {
                    tape.var(x.to_owned())
                } else {
                    tape.constant(x.to_owned())
                }
            })
            .collect();
        let outputs = (self.f)(&tape, &vars)?;
        let seeds: Vec<_> = args
            .grad_outputs
            .iter()
            .map(|g| g.as_ref().map(|g| g.to_owned()))
            .collect();
        let Some(total) = seeded_sum(&tape, &outputs, &seeds)? else {
            return Ok(vec![None; vars.len()]);
        };
        let wrt: Vec<_> = vars.iter().copied().filter(|v| v.requires_grad()).collect();
        let grads = tape.backward(total, &wrt)?;
        Ok(vars
            .iter()
            .enumerate()
            .map(|(i, v)| {
                if args.needs(i) {
                    grads.get(*v).cloned()
                } else {
                    None
                }
            })
            .collect())
    }
}

/// Steps `range` of an unroll recorded as one node: inputs are the state and then
/// the parameters, outputs the state after the last step.
struct StepSegment<T: Real> {
    range: std::ops::Range<usize>,
    state_len: usize,
    step: Rc<StepFn<T>>,
    check_finite: bool,
    name: String,
}

impl<T: Real> StepSegment<T> {
    fn scratch(&self) -> Tape<T> {
        scratch_tape(self.check_finite)
    }

    /// Step `k` from `state` without recording, on a scratch tape dropped after.
    fn advance(
        &self,
        k: usize,
        state: &[ArrayD<T>],
        params: &[ArrayViewD<'_, T>],
        pass: &'static str,
    ) -> Result<Vec<ArrayD<T>>> {
        let tape = self.scratch();
        let s: Vec<_> = state.iter().map(|x| tape.constant(x.clone())).collect();
        let p: Vec<_> = params.iter().map(|x| tape.constant(x.to_owned())).collect();
        let next = (self.step)(&tape, k, &s, &p).map_err(at_step(k, pass))?;
        if next.len() != self.state_len {
            return Err(TapeError::invalid(
                &self.name,
                format!(
                    "step {k} returned {} state arrays, expected {}",
                    next.len(),
                    self.state_len
                ),
            ));
        }
        Ok(arrays(&next))
    }
}

impl<T: Real> Op<T> for StepSegment<T> {
    fn name(&self) -> &str {
        &self.name
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        let (state, params) = inputs.split_at(self.state_len);
        let mut state: Vec<_> = state.iter().map(|x| x.to_owned()).collect();
        for k in self.range.clone() {
            state = self.advance(k, &state, params, "forward")?;
        }
        Ok(state)
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let (state0, params) = args.inputs.split_at(self.state_len);
        // The states before each step of the segment, recomputed from its checkpoint.
        let mut states = vec![state0.iter().map(|x| x.to_owned()).collect::<Vec<_>>()];
        for k in self.range.clone().skip(1) {
            let next = self.advance(
                k - 1,
                states.last().expect("one state"),
                params,
                "recomputation",
            )?;
            states.push(next);
        }
        let mut grad_state: Vec<Option<ArrayD<T>>> = args
            .grad_outputs
            .iter()
            .map(|g| g.as_ref().map(|g| g.to_owned()))
            .collect();
        let mut grad_params: Vec<Option<ArrayD<T>>> = vec![None; params.len()];
        let params_need: Vec<bool> = (0..params.len())
            .map(|j| args.needs(self.state_len + j))
            .collect();
        for (k, state) in self.range.clone().zip(&states).rev() {
            let tape = self.scratch();
            let s: Vec<_> = state.iter().map(|x| tape.var(x.clone())).collect();
            let p: Vec<_> = params
                .iter()
                .zip(&params_need)
                .map(|(x, &need)| {
                    if need {
                        tape.var(x.to_owned())
                    } else {
                        tape.constant(x.to_owned())
                    }
                })
                .collect();
            let next = (self.step)(&tape, k, &s, &p).map_err(at_step(k, "recomputation"))?;
            let Some(total) =
                seeded_sum(&tape, &next, &grad_state).map_err(at_step(k, "backward"))?
            else {
                // No gradient reaches this step's output, so none reaches earlier ones.
                return Ok(vec![None; args.inputs.len()]);
            };
            let wrt: Vec<_> = s
                .iter()
                .chain(p.iter().filter(|v| v.requires_grad()))
                .copied()
                .collect();
            let grads = tape.backward(total, &wrt).map_err(at_step(k, "backward"))?;
            grad_state = s.iter().map(|v| grads.get(*v).cloned()).collect();
            for (acc, v) in grad_params.iter_mut().zip(&p) {
                if v.requires_grad() {
                    add_into(acc, grads.get(*v));
                }
            }
        }
        Ok(grad_state
            .into_iter()
            .enumerate()
            .map(|(i, g)| if args.needs(i) { g } else { None })
            .chain(grad_params)
            .collect())
    }
}

impl<T: Real> Tape<T> {
    /// Records `f` applied to `inputs` as one node that keeps only the inputs and
    /// the outputs. The forward runs `f` on a scratch tape that is dropped at once;
    /// the backward runs it again on a scratch tape with the inputs as variables
    /// and sweeps that tape. The gradients equal those of recording `f` directly
    /// (for a deterministic `f`), at the cost of one more forward.
    ///
    /// `f` may use checkpoints itself (nesting). Everything `f` reads that needs a
    /// gradient must be among `inputs`; what it captures is a constant.
    ///
    /// # Errors
    /// Whatever `f` returns; errors of the recomputation in the backward sweep are
    /// wrapped as [`TapeError::Op`] naming `name`.
    pub fn checkpoint<'t>(
        &'t self,
        name: &str,
        f: Rc<SegmentFn<T>>,
        inputs: &[Var<'t, T>],
    ) -> Result<Vec<Var<'t, T>>> {
        let op = Checkpoint {
            name: name.to_string(),
            f,
            check_finite: self.checks_finite(),
        };
        self.apply_multi(op, inputs)
    }
}

/// Runs steps `0..steps` of `step` from `state` with parameters `params`,
/// stored by `schedule`, and returns the final state. With [`Schedule::Full`]
/// every step is recorded on `tape` directly; otherwise segments are checkpointed
/// (see the module docs) and the gradients are those of the full tape.
///
/// # Errors
/// [`TapeError::InvalidArgument`] for `Every(0)` or `Nested` with fewer than two
/// branches, or a step that returns a state of another length; an error of
/// `step` wrapped as [`TapeError::Op`] naming the step.
pub fn checkpointed_steps<'t, T: Real>(
    tape: &'t Tape<T>,
    schedule: Schedule,
    steps: usize,
    state: &[Var<'t, T>],
    params: &[Var<'t, T>],
    step: Rc<StepFn<T>>,
) -> Result<Vec<Var<'t, T>>> {
    match schedule {
        Schedule::Full => {
            let mut s = state.to_vec();
            for k in 0..steps {
                s = step(tape, k, &s, params).map_err(at_step(k, "forward"))?;
            }
            Ok(s)
        }
        Schedule::Every(0) => Err(TapeError::invalid(
            "checkpointed_steps",
            "a checkpoint every 0 steps",
        )),
        Schedule::Every(m) => {
            let mut s = state.to_vec();
            for start in (0..steps).step_by(m) {
                s = segment(tape, start..(start + m).min(steps), &s, params, &step)?;
            }
            Ok(s)
        }
        Schedule::Nested { branches } if branches < 2 => Err(TapeError::invalid(
            "checkpointed_steps",
            format!("nested checkpoints need at least 2 branches, got {branches}"),
        )),
        Schedule::Nested { branches } => nested(tape, 0..steps, branches, state, params, &step),
    }
}

/// One checkpointed segment of steps.
fn segment<'t, T: Real>(
    tape: &'t Tape<T>,
    range: std::ops::Range<usize>,
    state: &[Var<'t, T>],
    params: &[Var<'t, T>],
    step: &Rc<StepFn<T>>,
) -> Result<Vec<Var<'t, T>>> {
    let op = StepSegment {
        name: format!("checkpointed steps {}..{}", range.start, range.end),
        range,
        state_len: state.len(),
        step: Rc::clone(step),
        check_finite: tape.checks_finite(),
    };
    let inputs: Vec<_> = state.iter().chain(params).copied().collect();
    tape.apply_multi(op, &inputs)
}

/// `range` split into `branches` parts, each checkpointed; parts longer than
/// `branches` steps are themselves split, inside their checkpoint.
fn nested<'t, T: Real>(
    tape: &'t Tape<T>,
    range: std::ops::Range<usize>,
    branches: usize,
    state: &[Var<'t, T>],
    params: &[Var<'t, T>],
    step: &Rc<StepFn<T>>,
) -> Result<Vec<Var<'t, T>>> {
    let len = range.len();
    if len <= branches {
        return segment(tape, range, state, params, step);
    }
    let part = len.div_ceil(branches);
    let mut s = state.to_vec();
    for start in range.clone().step_by(part) {
        let sub = start..(start + part).min(range.end);
        let state_len = s.len();
        let inner_step = Rc::clone(step);
        let f: Rc<SegmentFn<T>> = Rc::new(move |t, v| {
            let (st, p) = v.split_at(state_len);
            nested(t, sub.clone(), branches, st, p, &inner_step)
        });
        let inputs: Vec<_> = s.iter().chain(params).copied().collect();
        s = tape.checkpoint(
            &format!(
                "checkpointed steps {}..{}",
                start,
                (start + part).min(range.end)
            ),
            f,
            &inputs,
        )?;
    }
    Ok(s)
}
