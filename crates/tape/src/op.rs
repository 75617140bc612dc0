//! The one trait through which primitives and plugins join the tape.

use ndarray::{ArrayD, ArrayViewD};

use crate::{Real, Result, TapeError};

/// What an op's backward receives: its inputs and outputs as recorded on the tape,
/// the gradients that reached its outputs, and which inputs need a gradient.
///
/// The tape keeps every input and output value, so an op need not save them itself;
/// [`Op::saved_bytes`] counts only what an op keeps beyond them.
pub struct BackwardArgs<'a, T: Real> {
    /// The op's input values, in the order they were passed to [`crate::Tape::apply`].
    pub inputs: &'a [ArrayViewD<'a, T>],
    /// The op's output values, in the order its forward returned them.
    pub outputs: &'a [ArrayViewD<'a, T>],
    /// The gradient of the loss with respect to each output; `None` where no
    /// gradient reached that output (the loss does not depend on it).
    pub grad_outputs: &'a [Option<ArrayViewD<'a, T>>],
    /// `needs_grad[i]` is true where input `i` lies on a path from a requested
    /// variable; the op should return `None` for every other input.
    pub needs_grad: &'a [bool],
}

impl<'a, T: Real> BackwardArgs<'a, T> {
    /// Input `i`.
    pub fn input(&self, i: usize) -> &ArrayViewD<'a, T> {
        &self.inputs[i]
    }

    /// Output `i`.
    pub fn output(&self, i: usize) -> &ArrayViewD<'a, T> {
        &self.outputs[i]
    }

    /// Whether input `i` needs a gradient.
    pub fn needs(&self, i: usize) -> bool {
        self.needs_grad[i]
    }

    /// The gradient reaching output `i`, or zeros of that output's shape where none did.
    pub fn grad_output_or_zeros(&self, i: usize) -> ArrayD<T> {
        match &self.grad_outputs[i] {
            Some(g) => g.to_owned(),
            None => ArrayD::zeros(self.outputs[i].raw_dim()),
        }
    }

    /// The gradient reaching output 0, the usual case of a single-output op.
    ///
    /// # Panics
    /// Only on a broken tape invariant: the tape calls backward only when at least
    /// one output received a gradient, so a single-output op always has it.
    pub fn grad_out(&self) -> &ArrayViewD<'a, T> {
        self.grad_outputs[0].as_ref().expect(
            "tape invariant: a single-output op is only swept when its output has a gradient",
        )
    }
}

/// An operation that can be recorded on a [`crate::Tape`]: a primitive (add, exp,
/// matmul, …) or a plugin (advection, a Poisson solve, …). The reverse sweep knows
/// ops only through this trait.
///
/// Required: [`Op::name`] and [`Op::forward`]. [`Op::backward`] defaults to
/// [`TapeError::BackwardNotSupported`], so a forward-only op is a valid plugin.
///
/// # Example: a plugin with a hand-written adjoint
/// ```
/// use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, Result, Tape};
///
/// /// y = x³, adjoint: grad_x = 3 x² grad_y.
/// struct Cube;
/// impl<T: Real> Op<T> for Cube {
///     fn name(&self) -> &str { "cube" }
///     fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
///         Ok(vec![inputs[0].mapv(|x| x * x * x)])
///     }
///     fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
///         let three = T::from_f64(3.0);
///         let g = ndarray::Zip::from(args.input(0))
///             .and(args.grad_out())
///             .map_collect(|&x, &g| three * x * x * g);
///         Ok(vec![Some(g)])
///     }
/// }
///
/// let tape = Tape::<f64>::new();
/// let x = tape.var(ndarray::arr1(&[2.0]).into_dyn());
/// let y = tape.apply(Cube, &[x])?.sum()?;
/// let grads = tape.backward(y, &[x])?;
/// assert_eq!(grads.get(x).unwrap()[[0]], 12.0);
/// # Ok::<(), diffphys_tape::TapeError>(())
/// ```
pub trait Op<T: Real> {
    /// A short name for error messages and statistics.
    fn name(&self) -> &str;

    /// Computes the outputs from the inputs. May record in `self` whatever the
    /// backward needs beyond the tape's inputs and outputs.
    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>>;

    /// Maps the gradients reaching the outputs to gradients of the inputs (a
    /// vector–Jacobian product). Returns one entry per input, `None` for inputs
    /// that do not need one (see [`BackwardArgs::needs_grad`]) or that the outputs
    /// do not depend on.
    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let _ = args;
        Err(TapeError::BackwardNotSupported {
            op: self.name().to_string(),
        })
    }

    /// Bytes this op keeps for its backward beyond the inputs and outputs the tape
    /// already holds (counted in [`crate::TapeStats`]).
    fn saved_bytes(&self) -> usize {
        0
    }
}
