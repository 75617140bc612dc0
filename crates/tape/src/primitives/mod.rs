//! Primitive ops, one family per file, each a kernel and its derivative behind the
//! [`Op`](crate::Op) trait, exposed as methods on [`Var`](crate::Var).

mod binary;
pub mod broadcast;
mod reduce;
