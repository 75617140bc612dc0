//! The preconditioner `M ≈ A` of CG, applied as `z = M⁻¹ r`: a trait typed
//! over the scalar, the identity and Jacobi, and [`Preconditioning`], the
//! choice that [`CgParams`](super::CgParams) carries for either precision.
//!
//! CG knows preconditioners only through [`Preconditioner`]; the multigrid
//! cycle ([`crate::multigrid::Multigrid`]) is one implementor among others.

use std::borrow::Cow;
use std::fmt;
use std::sync::Arc;

use diffphys_tape::{PerPrecision, Real};

use super::CgError;
use crate::LinearOperator;

/// A symmetric positive definite `M ≈ A`, applied by CG as `z = M⁻¹ r` once
/// per iteration, in precision `T`.
///
/// For CG to stay valid `M⁻¹` must be a fixed linear map, symmetric and
/// positive definite (semidefinite on a null space that CG projects out).
pub trait Preconditioner<T: Real>: fmt::Debug + Send + Sync {
    /// A short name for errors and reports.
    fn name(&self) -> &str;

    /// The shape of the vectors it was built for, checked against the
    /// operator's before a solve; `None` (the default) if it fits any.
    fn shape(&self) -> Option<&[usize]> {
        None
    }

    /// `z = M⁻¹ r` on contiguous vectors of the operator's size.
    fn apply(&self, r: &[T], z: &mut [T]);

    /// What CG may fuse into its own passes instead of calling
    /// [`Preconditioner::apply`]: the identity (then `z = r` is never
    /// stored), a diagonal `M⁻¹` (multiplied into the residual update), or
    /// nothing (the default).
    fn structure(&self) -> Structure<'_, T> {
        Structure::General
    }
}

/// The form of a preconditioner that CG can exploit
/// ([`Preconditioner::structure`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum Structure<'a, T> {
    /// `M = I`.
    Identity,
    /// `M⁻¹ = diag(d)`, the entries `d` in the operator's row-major order.
    Diagonal(&'a [T]),
    /// Anything else: CG calls [`Preconditioner::apply`].
    General,
}

/// No preconditioning, `M = I`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Identity;

impl<T: Real> Preconditioner<T> for Identity {
    fn name(&self) -> &str {
        "identity"
    }

    fn apply(&self, r: &[T], z: &mut [T]) {
        z.copy_from_slice(r);
    }

    fn structure(&self) -> Structure<'_, T> {
        Structure::Identity
    }
}

/// Jacobi preconditioning, `M = diag(A)`, from
/// [`LinearOperator::diagonal`].
#[derive(Debug, Clone, PartialEq)]
pub struct Jacobi<T> {
    shape: Vec<usize>,
    /// `1 / diag(A)`.
    inv_diag: Vec<T>,
}

impl<T: Real> Jacobi<T> {
    /// `M = diag(op)`.
    ///
    /// # Errors
    /// [`CgError::InvalidArgument`] if the operator gives no diagonal,
    /// [`CgError::NonFinite`] for a NaN or infinite entry and
    /// [`CgError::NotPositiveDefinite`] for an entry `≤ 0`.
    pub fn new<A: LinearOperator<T> + ?Sized>(op: &A) -> Result<Self, CgError> {
        let d = op.diagonal().ok_or_else(|| {
            CgError::invalid(format!(
                "operator {} gives no diagonal (LinearOperator::diagonal) for Jacobi",
                op.name()
            ))
        })?;
        let mut inv_diag = Vec::with_capacity(d.len());
        for &v in d.iter() {
            if !v.is_finite() {
                return Err(CgError::non_finite(0, "the diagonal (Jacobi)"));
            }
            if v <= T::zero() {
                return Err(CgError::NotPositiveDefinite {
                    iteration: 0,
                    curvature: v.as_f64(),
                });
            }
            inv_diag.push(T::one() / v);
        }
        Ok(Jacobi {
            shape: d.shape().to_vec(),
            inv_diag,
        })
    }
}

impl<T: Real> Preconditioner<T> for Jacobi<T> {
    fn name(&self) -> &str {
        "jacobi"
    }

    fn shape(&self) -> Option<&[usize]> {
        Some(&self.shape)
    }

    fn apply(&self, r: &[T], z: &mut [T]) {
        for ((z, &r), &d) in z.iter_mut().zip(r).zip(&self.inv_diag) {
            *z = r * d;
        }
    }

    fn structure(&self) -> Structure<'_, T> {
        Structure::Diagonal(&self.inv_diag)
    }
}

/// A preconditioner in both precisions, as [`Preconditioning::Shared`] holds
/// it: implemented for every type that is a [`Preconditioner`] of `f32` and
/// of `f64`.
pub trait SharedPreconditioner: fmt::Debug + Send + Sync {
    /// As a preconditioner of `f32` vectors.
    fn single(&self) -> &dyn Preconditioner<f32>;
    /// As a preconditioner of `f64` vectors.
    fn double(&self) -> &dyn Preconditioner<f64>;
}

impl<P: Preconditioner<f32> + Preconditioner<f64>> SharedPreconditioner for P {
    fn single(&self) -> &dyn Preconditioner<f32> {
        self
    }

    fn double(&self) -> &dyn Preconditioner<f64> {
        self
    }
}

/// `&dyn Preconditioner<T>`, one per precision ([`Real::pick`]).
struct DynRef<'a>(std::marker::PhantomData<&'a ()>);

impl<'a> PerPrecision for DynRef<'a> {
    type Of<T: Real> = &'a dyn Preconditioner<T>;
}

/// The preconditioner that [`CgParams`](super::CgParams) asks for, in a form
/// that serves solves in either precision.
#[derive(Debug, Clone, Default)]
#[non_exhaustive]
pub enum Preconditioning {
    /// None, `M = I` ([`Identity`]).
    #[default]
    None,
    /// [`Jacobi`] of the solve's operator, built when the solve starts.
    Jacobi,
    /// A preconditioner built beforehand for the operator, shared between
    /// solves (a [`crate::multigrid::Multigrid`] cycle); `From<Arc<P>>`
    /// builds it.
    Shared(Arc<dyn SharedPreconditioner>),
}

impl<P: SharedPreconditioner + 'static> From<Arc<P>> for Preconditioning {
    fn from(p: Arc<P>) -> Self {
        Preconditioning::Shared(p)
    }
}

impl PartialEq for Preconditioning {
    /// Equal kinds; two shared preconditioners are equal if they are the
    /// same one (the same `Arc`).
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Preconditioning::None, Preconditioning::None)
            | (Preconditioning::Jacobi, Preconditioning::Jacobi) => true,
            (Preconditioning::Shared(a), Preconditioning::Shared(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

/// A preconditioner of one precision as the solver applies it.
pub(super) enum Applied<'a, T: Clone> {
    /// `z = r`: nothing to apply.
    Identity,
    /// `z = d ⊙ r`, fused into the residual update.
    Diagonal(Cow<'a, [T]>),
    /// `z` from [`Preconditioner::apply`].
    General(&'a dyn Preconditioner<T>),
}

impl Preconditioning {
    /// The preconditioner of precision `T` for `op` (of shape `shape`):
    /// borrowed when shared, built now for Jacobi.
    pub(super) fn resolve<'a, T: Real, A: LinearOperator<T> + ?Sized>(
        &'a self,
        op: &A,
        shape: &[usize],
    ) -> Result<Applied<'a, T>, CgError> {
        let shared = match self {
            Preconditioning::None => return Ok(Applied::Identity),
            Preconditioning::Jacobi => {
                let jacobi = Jacobi::new(op)?;
                return Ok(Applied::Diagonal(Cow::Owned(jacobi.inv_diag)));
            }
            Preconditioning::Shared(p) => T::pick::<DynRef<'a>>(p.single(), p.double()),
        };
        if let Some(found) = shared.shape() {
            if found != shape {
                return Err(CgError::ShapeMismatch {
                    what: format!("preconditioner {}", shared.name()),
                    expected: shape.to_vec(),
                    found: found.to_vec(),
                });
            }
        }
        Ok(match shared.structure() {
            Structure::Identity => Applied::Identity,
            Structure::Diagonal(d) if d.len() != shape.iter().product::<usize>() => {
                return Err(CgError::ShapeMismatch {
                    what: format!("diagonal of preconditioner {}", shared.name()),
                    expected: shape.to_vec(),
                    found: vec![d.len()],
                })
            }
            Structure::Diagonal(d) => Applied::Diagonal(Cow::Borrowed(d)),
            Structure::General => Applied::General(shared),
        })
    }
}
