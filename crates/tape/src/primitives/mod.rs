//! Primitive ops, one family per file, each a kernel and its derivative behind the
//! [`Op`](crate::Op) trait, exposed as methods on [`Var`](crate::Var).
//!
//! | family | file | ops |
//! |---|---|---|
//! | elementwise binary, broadcasting | `binary.rs` | `add`, `sub`, `mul`, `div`, `minimum`, `maximum` |
//! | elementwise unary | `unary.rs` | `neg`, `add_scalar`, `mul_scalar`, `powi`, `exp`, `ln`, `sqrt`, `sin`, `cos`, `tanh`, `relu`, `sigmoid`, `abs` |
//! | selection by mask | `select.rs` | `select` |
//! | reductions | `reduce.rs` | `sum`, `sum_axis`, `mean`, `dot` |
//! | linear algebra (2-D) | `linalg.rs` | `matmul`, `transpose` |
//! | shape | `shape.rs` | `reshape`, `broadcast_to`, `slice`, `roll`, `pad`, `concat` |
//!
//! The generic bookkeeping lives beside the kernels: `Binary` and `Unary` map a
//! kernel and its derivative, `Linear` adapts a linear map and its adjoint (see
//! [`broadcast`] for broadcasting and its adjoint).

mod binary;
pub mod broadcast;
mod linalg;
mod linear;
mod reduce;
mod select;
mod shape;
mod unary;

use crate::{Result, TapeError};

/// Checks that `axis` is an axis of `shape`; the error names `op`.
pub(crate) fn check_axis(op: &str, axis: usize, shape: &[usize]) -> Result<()> {
    if axis < shape.len() {
        Ok(())
    } else {
        Err(TapeError::invalid(
            op,
            format!("axis {axis} is out of range for shape {shape:?}"),
        ))
    }
}
