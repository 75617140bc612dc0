//! NumPy-style broadcasting and its adjoint, summing a gradient back to a shape.

use ndarray::{ArrayD, ArrayViewD, Axis, CowArray};

use crate::{Real, Result, TapeError};

/// The shape two shapes broadcast to (NumPy rules: align trailing axes; each pair
/// must be equal or contain a 1).
///
/// # Errors
/// [`TapeError::ShapeMismatch`] naming `op` if they do not broadcast.
pub fn broadcast_shape(op: &str, lhs: &[usize], rhs: &[usize]) -> Result<Vec<usize>> {
    let ndim = lhs.len().max(rhs.len());
    let dim = |s: &[usize], k: usize| -> usize {
        // k counts from the last axis
        if k < s.len() {
            s[s.len() - 1 - k]
        } else {
            1
        }
    };
    let mut out = vec![0; ndim];
    for k in 0..ndim {
        let (a, b) = (dim(lhs, k), dim(rhs, k));
        out[ndim - 1 - k] = match (a, b) {
            _ if a == b => a,
            (1, _) => b,
            (_, 1) => a,
            _ => return Err(TapeError::shape(op, lhs, rhs)),
        };
    }
    Ok(out)
}

/// The adjoint of broadcasting a value of `shape` to `grad`'s shape: sums `grad`
/// over the axes that broadcasting added or stretched.
///
/// # Panics
/// Only if `shape` does not broadcast to `grad.shape()` (an internal invariant: the
/// forward checked it).
pub fn sum_to_shape<T: Real>(grad: ArrayViewD<'_, T>, shape: &[usize]) -> ArrayD<T> {
    if grad.shape() == shape {
        return grad.to_owned();
    }
    sum_broadcast_axes(grad, shape)
}

/// [`sum_to_shape`] of an owned gradient: returns it unchanged (no copy) where no
/// axis was broadcast.
pub(crate) fn sum_to_shape_owned<T: Real>(grad: ArrayD<T>, shape: &[usize]) -> ArrayD<T> {
    if grad.shape() == shape {
        return grad;
    }
    sum_broadcast_axes(grad.view(), shape)
}

fn sum_broadcast_axes<T: Real>(grad: ArrayViewD<'_, T>, shape: &[usize]) -> ArrayD<T> {
    assert!(
        grad.ndim() >= shape.len(),
        "sum_to_shape: {shape:?} does not broadcast to the gradient {:?}",
        grad.shape()
    );
    let lead = grad.ndim() - shape.len();
    let mut g = CowArray::from(grad);
    for _ in 0..lead {
        g = g.sum_axis(Axis(0)).into();
    }
    for (axis, &n) in shape.iter().enumerate() {
        if n == 1 && g.shape()[axis] != 1 {
            g = g.sum_axis(Axis(axis)).insert_axis(Axis(axis)).into();
        }
    }
    assert_eq!(
        g.shape(),
        shape,
        "sum_to_shape: {shape:?} does not broadcast to the gradient"
    );
    g.into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_broadcast_by_numpy_rules() {
        assert_eq!(broadcast_shape("t", &[3, 1], &[4]).unwrap(), vec![3, 4]);
        assert_eq!(broadcast_shape("t", &[], &[2, 2]).unwrap(), vec![2, 2]);
        assert!(broadcast_shape("t", &[3], &[4]).is_err());
    }

    #[test]
    fn sum_to_shape_sums_stretched_axes() {
        let g = ArrayD::from_elem(vec![2, 3, 4], 1.0_f64);
        let s = sum_to_shape(g.view(), &[3, 1]);
        assert_eq!(s.shape(), &[3, 1]);
        assert_eq!(s[[0, 0]], 8.0);
    }
}
