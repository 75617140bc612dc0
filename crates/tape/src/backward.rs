//! The reverse sweep. It knows ops only through [`Op::backward`](crate::Op::backward).

use std::collections::HashMap;

use ndarray::{ArrayD, ArrayViewD};
use smallvec::SmallVec;

use crate::tape::check_finite;
use crate::{BackwardArgs, Pass, Real, Result, Tape, TapeError, Var};

/// Gradients of a loss with respect to the requested variables, read as
/// `grads.get(x)`.
#[derive(Debug, Clone)]
pub struct Gradients<T: Real> {
    tape_id: u64,
    grads: HashMap<usize, ArrayD<T>>,
    nodes_visited: usize,
}

impl<T: Real> Gradients<T> {
    /// The gradient with respect to `v`, if `v` was requested (zeros where the
    /// loss does not depend on it); `None` for a variable that was not requested
    /// or that belongs to another tape.
    pub fn get(&self, v: Var<'_, T>) -> Option<&ArrayD<T>> {
        if v.tape.id() != self.tape_id {
            return None;
        }
        self.grads.get(&v.index)
    }

    /// The gradient with respect to `v`.
    ///
    /// # Errors
    /// [`TapeError::NoGradient`] if `v` was not requested or belongs to another
    /// tape.
    pub fn try_get(&self, v: Var<'_, T>) -> Result<&ArrayD<T>> {
        self.get(v).ok_or(TapeError::NoGradient {
            index: v.index,
            tape: v.tape.id(),
        })
    }

    /// Takes the gradient with respect to `v` out of the container.
    pub fn take(&mut self, v: Var<'_, T>) -> Option<ArrayD<T>> {
        if v.tape.id() != self.tape_id {
            return None;
        }
        self.grads.remove(&v.index)
    }

    /// How many op nodes the sweep called backward on: only those between the
    /// requested variables and the loss.
    pub fn nodes_visited(&self) -> usize {
        self.nodes_visited
    }
}

impl<T: Real> Tape<T> {
    /// Gradients of the scalar `loss` with respect to each of `wrt`.
    ///
    /// Only the nodes that lie on a path from a variable in `wrt` to `loss` are
    /// visited, and an op is asked only for the input gradients on such a path.
    /// Where a value is used more than once its gradients are summed.
    ///
    /// # Errors
    /// [`TapeError::NonScalarLoss`] if `loss` has more than one element (use
    /// [`Tape::backward_with_seed`]), [`TapeError::ForeignVar`] for a variable of
    /// another tape, and whatever an op's backward returns, including
    /// [`TapeError::NonFinite`] for a NaN or infinite gradient.
    pub fn backward(&self, loss: Var<'_, T>, wrt: &[Var<'_, T>]) -> Result<Gradients<T>> {
        self.check_owned("backward", &loss)?;
        let shape = loss.shape();
        if shape.iter().product::<usize>() != 1 {
            return Err(TapeError::NonScalarLoss { shape });
        }
        let seed = ArrayD::from_elem(shape, T::one());
        self.backward_with_seed(loss, seed, wrt)
    }

    /// Gradients of `<seed, output>` with respect to each of `wrt`: the
    /// vector–Jacobian product of a non-scalar output.
    ///
    /// # Errors
    /// As [`Tape::backward`], and [`TapeError::ShapeMismatch`] if `seed` does not
    /// have the output's shape.
    pub fn backward_with_seed(
        &self,
        output: Var<'_, T>,
        seed: ArrayD<T>,
        wrt: &[Var<'_, T>],
    ) -> Result<Gradients<T>> {
        self.check_owned("backward", &output)?;
        for v in wrt {
            self.check_owned("backward", v)?;
        }
        let _current = self.pool().install();
        let inner = self.inner.borrow();
        let out_shape = inner.slots[output.index].data.shape();
        if seed.shape() != out_shape {
            return Err(TapeError::shape("backward seed", seed.shape(), out_shape));
        }

        // Values downstream of a requested variable: only they can carry a gradient.
        let n = inner.slots.len();
        let mut from_wrt = vec![false; n];
        let mut requested = vec![false; n];
        for v in wrt {
            from_wrt[v.index] = true;
            requested[v.index] = true;
        }
        for node in &inner.nodes {
            if node.inputs.iter().any(|&i| from_wrt[i]) {
                for &o in &node.outputs {
                    from_wrt[o] = true;
                }
            }
        }

        let mut grads: Vec<Option<ArrayD<T>>> = (0..n).map(|_| None).collect();
        if from_wrt[output.index] {
            grads[output.index] = Some(seed);
        }
        let mut nodes_visited = 0;
        for node in inner.nodes.iter().rev() {
            if !node.outputs.iter().any(|&o| grads[o].is_some()) {
                continue;
            }
            // Gradients of intermediates are freed as soon as they are consumed.
            let grad_outputs: SmallVec<[Option<ArrayD<T>>; 2]> = node
                .outputs
                .iter()
                .map(|&o| {
                    if requested[o] {
                        grads[o].clone()
                    } else {
                        grads[o].take()
                    }
                })
                .collect();
            let needs_grad: SmallVec<[bool; 4]> =
                node.inputs.iter().map(|&i| from_wrt[i]).collect();
            let inputs: SmallVec<[ArrayViewD<'_, T>; 4]> = node
                .inputs
                .iter()
                .map(|&i| inner.slots[i].data.view())
                .collect();
            let outputs: SmallVec<[ArrayViewD<'_, T>; 2]> = node
                .outputs
                .iter()
                .map(|&o| inner.slots[o].data.view())
                .collect();
            let grad_views: SmallVec<[Option<ArrayViewD<'_, T>>; 2]> = grad_outputs
                .iter()
                .map(|g| g.as_ref().map(|g| g.view()))
                .collect();
            let args = BackwardArgs {
                inputs: &inputs,
                outputs: &outputs,
                grad_outputs: &grad_views,
                needs_grad: &needs_grad,
            };
            let name = node.op.name();
            let grad_inputs = node.op.backward(&args)?;
            nodes_visited += 1;
            if grad_inputs.len() != node.inputs.len() {
                return Err(TapeError::invalid(
                    name,
                    format!(
                        "backward returned {} gradients for {} inputs",
                        grad_inputs.len(),
                        node.inputs.len()
                    ),
                ));
            }
            for ((&i, g), &needed) in node.inputs.iter().zip(grad_inputs).zip(&needs_grad) {
                let Some(g) = g.filter(|_| needed) else {
                    continue;
                };
                let want = inner.slots[i].data.shape();
                if g.shape() != want {
                    return Err(TapeError::shape(
                        &format!("backward of {name}"),
                        g.shape(),
                        want,
                    ));
                }
                if self.checks_finite() {
                    check_finite(name, Pass::Backward, &g.view())?;
                }
                match &mut grads[i] {
                    Some(acc) => {
                        accumulate(acc, &g);
                        crate::pool::recycle_array(g);
                    }
                    slot => *slot = Some(g),
                }
            }
            drop(grad_views);
            for g in grad_outputs.into_iter().flatten() {
                crate::pool::recycle_array(g);
            }
        }

        let mut requested_grads = HashMap::with_capacity(wrt.len());
        for v in wrt {
            requested_grads.entry(v.index).or_insert_with(|| {
                grads[v.index]
                    .take()
                    .unwrap_or_else(|| ArrayD::zeros(inner.slots[v.index].data.raw_dim()))
            });
        }
        Ok(Gradients {
            tape_id: self.id(),
            grads: requested_grads,
            nodes_visited,
        })
    }
}

/// `acc += g` (same shapes), in parallel for large contiguous arrays.
fn accumulate<T: Real>(acc: &mut ArrayD<T>, g: &ArrayD<T>) {
    let same_layout = acc.is_standard_layout() && g.is_standard_layout();
    match (acc.as_slice_mut(), g.as_slice()) {
        (Some(a), Some(b)) if same_layout => {
            crate::parallel::for_each_chunk_mut(a, |off, a| {
                let n = a.len();
                for (a, &b) in a.iter_mut().zip(&b[off..off + n]) {
                    *a += b;
                }
            });
        }
        _ => *acc += g,
    }
}

impl<'t, T: Real> Var<'t, T> {
    /// `self.tape().backward(self, wrt)`: gradients of this scalar.
    ///
    /// # Errors
    /// As [`Tape::backward`].
    pub fn backward(self, wrt: &[Var<'t, T>]) -> Result<Gradients<T>> {
        self.tape.backward(self, wrt)
    }
}
