//! A learned initial guess for conjugate gradient, trained with CG iterations as
//! virtual time.
//!
//! A network maps a right-hand side `b` to an initial guess `x₀`; it is trained
//! either supervised, loss `mean ‖x₀ − x*‖² / ‖x*‖²`, or through the solver:
//! `k` CG iterations from `x₀` recorded on the tape, loss `mean ‖r_k‖² / ‖b‖²`.
//! The implicit gradient of the converged solution with respect to `x₀` is zero,
//! so the unrolled gradient through the `k` iterations is the one that exists.
//!
//! Both trainings get the same budget (steps × batch of fresh problems from the
//! same stream); early stopping reads the validation split only: the mean number
//! of CG iterations to the validation tolerances.

use std::sync::Arc;

use diffphys_nn::{Bound, Params};
use diffphys_ops::cg::{conjugate_gradient, CgParams};
use diffphys_ops::tape_ops::LinearOp;
use diffphys_ops::LinearOperator;
use diffphys_tape::{ArrayD, ArrayViewD, IxDyn, Tape, Var};
use ndarray::{ArrayViewMutD, Axis};
use rand::rngs::StdRng;

use crate::data::{Split, Trained};
use crate::fit::{Fit, Validation};
use crate::hybrid::frozen;
use crate::metrics::batch_of;
use crate::strategy::LrSchedule;
use crate::{LearnError, Result};

/// A network proposing initial guesses.
pub trait InitialGuess {
    /// Records the guesses `x₀` for the batch of right-hand sides `b`, `[batch,
    /// 1, …]` (one channel, then the operator's shape), with the parameters
    /// `params` bound to `b`'s tape; the output has `b`'s shape.
    ///
    /// # Errors
    /// Whatever the network's layers return.
    fn guess<'t>(
        &self,
        params: &Bound<'t, f64>,
        b: Var<'t, f64>,
    ) -> diffphys_tape::Result<Var<'t, f64>>;
}

/// One linear problem `A x = b` and its solution, both of the operator's shape.
#[derive(Debug, Clone)]
pub struct GuessProblem {
    /// The right-hand side.
    pub b: ArrayD<f64>,
    /// The solution (for the supervised loss and the initial error).
    pub x_star: ArrayD<f64>,
}

/// `A` applied to every sample of a `[batch, 1, …]` field: one tape node per
/// batch.
#[derive(Debug, Clone)]
pub struct PerSample<A> {
    op: A,
    shape: Vec<usize>,
}

impl<A: LinearOperator<f64>> PerSample<A> {
    /// `op` over batches of `batch` one-channel samples.
    pub fn new(op: A, batch: usize) -> Self {
        let mut shape = vec![batch, 1];
        shape.extend_from_slice(op.input_shape());
        PerSample { op, shape }
    }
}

impl<A: LinearOperator<f64>> LinearOperator<f64> for PerSample<A> {
    fn name(&self) -> &str {
        "per-sample operator"
    }
    fn input_shape(&self) -> &[usize] {
        &self.shape
    }
    fn output_shape(&self) -> &[usize] {
        &self.shape
    }
    fn apply_into(&self, x: ArrayViewD<'_, f64>, mut out: ArrayViewMutD<'_, f64>) {
        for (xb, ob) in x.outer_iter().zip(out.outer_iter_mut()) {
            self.op.apply_into(
                xb.index_axis_move(Axis(0), 0),
                ob.index_axis_move(Axis(0), 0),
            );
        }
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, f64>, mut out: ArrayViewMutD<'_, f64>) {
        for (yb, ob) in y.outer_iter().zip(out.outer_iter_mut()) {
            self.op.apply_transpose_into(
                yb.index_axis_move(Axis(0), 0),
                ob.index_axis_move(Axis(0), 0),
            );
        }
    }
    fn is_symmetric(&self) -> bool {
        self.op.is_symmetric()
    }
}

/// Records `A x` (the shim over the tape's op-recording call).
fn record_linear<'t, A: LinearOperator<f64> + 'static>(
    op: A,
    x: Var<'t, f64>,
) -> diffphys_tape::Result<Var<'t, f64>> {
    x.tape().apply(LinearOp::new(op), &[x])
}

/// `<a_b, c_b>` for every sample `b` of a batch, shaped `[batch, 1, 1, …]` to
/// broadcast against it.
fn batch_dot<'t>(a: Var<'t, f64>, c: Var<'t, f64>) -> diffphys_tape::Result<Var<'t, f64>> {
    let shape = a.shape();
    let batch = shape[0];
    let per = a
        .mul(c)?
        .reshape(&[batch, shape[1..].iter().product()])?
        .sum_axis(1)?;
    let mut out = vec![batch];
    out.extend(std::iter::repeat_n(1, shape.len() - 1));
    per.reshape(&out)
}

/// Records `k` CG iterations for `A x = b` from `x0`, per sample of the batch,
/// and returns the residual `r_k` of the recurrence (equal to `b − A x_k` up to
/// rounding).
///
/// # Errors
/// Whatever the tape returns (shapes that do not fit `op`).
pub fn unrolled_cg_residual<'t, A: LinearOperator<f64> + 'static>(
    op: &Arc<PerSample<A>>,
    b: Var<'t, f64>,
    x0: Var<'t, f64>,
    k: usize,
) -> diffphys_tape::Result<Var<'t, f64>> {
    let apply = |v: Var<'t, f64>| record_linear(Arc::clone(op), v);
    let mut r = b.sub(apply(x0)?)?;
    let mut p = r;
    let mut rr = batch_dot(r, r)?;
    for _ in 0..k {
        let ap = apply(p)?;
        let alpha = rr.div(batch_dot(p, ap)?)?;
        r = r.sub(ap.mul(alpha)?)?;
        let rr_next = batch_dot(r, r)?;
        p = r.add(p.mul(rr_next.div(rr)?)?)?;
        rr = rr_next;
    }
    Ok(r)
}

/// How the guess is trained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GuessLoss {
    /// Loss `mean ‖x₀ − x*‖² / ‖x*‖²`.
    Supervised,
    /// Loss `mean ‖r_k‖² / ‖b‖²` after `iterations` recorded CG iterations.
    ThroughSolver {
        /// `k`, the unrolled CG iterations (at least 1).
        iterations: usize,
    },
}

impl GuessLoss {
    /// `supervised` or `through_cg_k`.
    pub fn name(&self) -> String {
        match *self {
            GuessLoss::Supervised => "supervised".into(),
            GuessLoss::ThroughSolver { iterations } => format!("through_cg_{iterations}"),
        }
    }
}

/// A problem's right-hand side as a one-channel sample.
fn channel(a: &ArrayD<f64>) -> ArrayD<f64> {
    a.clone().insert_axis(Axis(0))
}

fn norm(a: &ArrayD<f64>) -> f64 {
    a.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// Records the loss of `problems` under `loss` on `tape`.
///
/// # Errors
/// [`LearnError::ZeroUnroll`] for `ThroughSolver { iterations: 0 }`; whatever
/// the network and the tape return.
pub fn guess_loss<'t, A: LinearOperator<f64> + Clone + 'static, G: InitialGuess>(
    tape: &'t Tape<f64>,
    op: &A,
    guesser: &G,
    params: &Bound<'t, f64>,
    loss: GuessLoss,
    problems: &[&GuessProblem],
) -> Result<Var<'t, f64>> {
    let bs: Vec<ArrayD<f64>> = problems.iter().map(|p| channel(&p.b)).collect();
    let b = batch_of(&bs.iter().collect::<Vec<_>>())?;
    let x0 = guesser.guess(params, tape.constant(b.clone()))?;
    let (diff, scale): (Var<'t, f64>, Vec<f64>) = match loss {
        GuessLoss::Supervised => {
            let xs: Vec<ArrayD<f64>> = problems.iter().map(|p| channel(&p.x_star)).collect();
            let x_star = batch_of(&xs.iter().collect::<Vec<_>>())?;
            (
                x0.sub(tape.constant(x_star))?,
                problems.iter().map(|p| norm(&p.x_star).powi(-2)).collect(),
            )
        }
        GuessLoss::ThroughSolver { iterations: 0 } => {
            return Err(LearnError::ZeroUnroll {
                what: "CG iterations of the learned guess",
            })
        }
        GuessLoss::ThroughSolver { iterations } => {
            let a = Arc::new(PerSample::new(op.clone(), problems.len()));
            (
                unrolled_cg_residual(&a, tape.constant(b), x0, iterations)?,
                problems.iter().map(|p| norm(&p.b).powi(-2)).collect(),
            )
        }
    };
    let mut wshape = vec![problems.len()];
    wshape.extend(std::iter::repeat_n(1, diff.shape().len() - 1));
    let weights = tape.constant(
        ArrayD::from_shape_vec(IxDyn(&wshape), scale)
            .map_err(|e| LearnError::invalid("guess loss", e.to_string()))?,
    );
    Ok(batch_dot(diff, diff)?.mul(weights)?.mean()?)
}

/// The guesses for `bs` (each of the operator's shape) without a tape to keep;
/// `params = None` is the zero guess.
///
/// # Errors
/// Whatever the network returns.
pub fn guesses<G: InitialGuess>(
    guesser: &G,
    params: Option<&Params<f64>>,
    bs: &[&ArrayD<f64>],
) -> Result<Vec<ArrayD<f64>>> {
    let Some(params) = params else {
        return Ok(bs.iter().map(|b| ArrayD::zeros(b.raw_dim())).collect());
    };
    let channels: Vec<ArrayD<f64>> = bs.iter().map(|b| channel(b)).collect();
    let batch = batch_of(&channels.iter().collect::<Vec<_>>())?;
    let tape = Tape::new();
    let x0 = guesser
        .guess(&frozen(&tape, params), tape.constant(batch))?
        .to_array();
    Ok(x0
        .outer_iter()
        .map(|x| x.index_axis(Axis(0), 0).to_owned())
        .collect())
}

/// `‖b − A x‖ / ‖b‖`, computed here rather than read from the solver.
///
/// # Errors
/// The operator's shape errors.
pub fn true_relative_residual<A: LinearOperator<f64>>(
    op: &A,
    b: &ArrayD<f64>,
    x: &ArrayD<f64>,
) -> Result<f64> {
    let ax = op.apply(x.view())?;
    let r: f64 = b.iter().zip(ax.iter()).map(|(b, a)| (b - a).powi(2)).sum();
    Ok(r.sqrt() / norm(b))
}

/// CG iterations from `x0` to relative residual `tol`, after checking the true
/// residual of what the solver returned.
///
/// # Errors
/// CG's errors; [`LearnError::Invalid`] if the true residual misses `tol`.
pub fn iterations_to<A: LinearOperator<f64>>(
    op: &A,
    b: &ArrayD<f64>,
    x0: &ArrayD<f64>,
    tol: f64,
) -> Result<usize> {
    let mut x = x0.clone();
    let info = conjugate_gradient(
        op,
        b.view(),
        x.view_mut(),
        &CgParams::default().with_rel_tol(tol),
    )?;
    let measured = true_relative_residual(op, b, &x)?;
    if measured > tol {
        return Err(LearnError::invalid(
            "CG result",
            format!(
                "reported convergence to {tol:e} in {} iterations, true relative residual {measured:.3e}",
                info.iterations
            ),
        ));
    }
    Ok(info.iterations)
}

/// The mean over `problems` and `tolerances` of the CG iterations from the
/// guesses of `params` (`None`: the zero guess).
///
/// # Errors
/// As [`guesses`] and [`iterations_to`].
pub fn mean_iterations<A: LinearOperator<f64>, G: InitialGuess>(
    op: &A,
    guesser: &G,
    params: Option<&Params<f64>>,
    problems: &[GuessProblem],
    tolerances: &[f64],
) -> Result<f64> {
    let bs: Vec<&ArrayD<f64>> = problems.iter().map(|p| &p.b).collect();
    let x0s = guesses(guesser, params, &bs)?;
    let mut total = 0usize;
    for (p, x0) in problems.iter().zip(&x0s) {
        for &tol in tolerances {
            total += iterations_to(op, &p.b, x0, tol)?;
        }
    }
    Ok(total as f64 / (problems.len() * tolerances.len()).max(1) as f64)
}

/// What one guess training produced.
#[derive(Debug, Clone)]
pub struct TrainedGuess {
    /// The loss.
    pub loss: GuessLoss,
    /// The parameters at the best validation score.
    pub params: Params<f64>,
    /// The training loss per step.
    pub losses: Vec<f64>,
    /// `(step, validation score)` at every validation.
    pub validation_curve: Vec<(usize, f64)>,
    /// The step whose parameters were kept.
    pub best_step: usize,
    /// Their validation score: mean CG iterations to the validation tolerances.
    pub validation: f64,
}

/// Trains initial guesses with an equal budget for every [`GuessLoss`].
#[derive(Debug, Clone, PartialEq)]
pub struct GuessTrainer {
    /// Optimizer steps.
    pub steps: usize,
    /// Fresh problems per step.
    pub batch: usize,
    /// Adam's initial step size.
    pub learning_rate: f64,
    /// How it changes over training.
    pub schedule: LrSchedule,
    /// Validate every this many steps (and after the last); 0: after the last only.
    pub validate_every: usize,
    /// The validation score is the mean CG iterations to these relative residuals.
    pub validation_tolerances: Vec<f64>,
}

impl GuessTrainer {
    /// Trains `params` with `loss`; each step draws `batch` problems with
    /// `draw(rng)` from `data` (the training split's stream: pass the same
    /// stream to every loss for the same samples), validates on `validation`;
    /// `tick` runs after every step.
    ///
    /// # Errors
    /// [`LearnError::ZeroIterations`] for 0 steps, [`LearnError::Budget`] for a
    /// batch of 0, [`LearnError::ZeroUnroll`] for 0 CG iterations,
    /// [`LearnError::EmptySplit`] without validation problems; a non-finite loss;
    /// whatever `draw`, the network and CG return.
    #[allow(clippy::too_many_arguments)]
    pub fn train<A: LinearOperator<f64> + Clone + 'static, G: InitialGuess>(
        &self,
        op: &A,
        guesser: &G,
        params: Params<f64>,
        loss: GuessLoss,
        draw: &mut dyn FnMut(&mut StdRng) -> Result<GuessProblem>,
        mut data: StdRng,
        validation: &[GuessProblem],
        tick: &dyn Fn(),
    ) -> Result<Trained<TrainedGuess>> {
        if self.steps == 0 {
            return Err(LearnError::ZeroIterations {
                trainer: "guess trainer",
            });
        }
        if self.batch == 0 {
            return Err(LearnError::Budget {
                message: "a batch of 0 problems per step".into(),
            });
        }
        if loss == (GuessLoss::ThroughSolver { iterations: 0 }) {
            return Err(LearnError::ZeroUnroll {
                what: "CG iterations of the learned guess",
            });
        }
        if validation.is_empty() {
            return Err(LearnError::EmptySplit {
                split: Split::Validation,
                context: format!("early stopping of the {} guess", loss.name()),
            });
        }
        let fit = Fit {
            steps: self.steps,
            learning_rate: self.learning_rate,
            schedule: self.schedule,
            validate_every: self.validate_every,
            validation: Validation::Strict,
        };
        let fitted = fit.run(
            "guess trainer",
            params,
            |_, tape, p| {
                let batch = (0..self.batch)
                    .map(|_| draw(&mut data))
                    .collect::<Result<Vec<_>>>()?;
                let refs: Vec<&GuessProblem> = batch.iter().collect();
                guess_loss(tape, op, guesser, p, loss, &refs)
            },
            |params| {
                mean_iterations(
                    op,
                    guesser,
                    Some(params),
                    validation,
                    &self.validation_tolerances,
                )
            },
            tick,
        )?;
        Ok(Trained::new(TrainedGuess {
            loss,
            params: fitted.params,
            losses: fitted.losses,
            validation_curve: fitted.curve,
            best_step: fitted.best_step,
            validation: fitted.validation,
        }))
    }
}
