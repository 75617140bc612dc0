//! The exact reference: any symmetric [`LinearOperator<f64>`] that lists its
//! nonzeros ([`LinearOperator::triplets`]) assembled into a sparse matrix and
//! solved by faer's sparse Cholesky factorisation `A = L Lᵀ`.
//!
//! CG gradients are measured against it: the Cholesky solve is accurate to
//! about `ε·κ(A)`, independent of any iteration count or tolerance.
//!
//! ```
//! use diffphys_ops::cg::NullSpace;
//! use diffphys_ops::reference::SparseCholesky;
//! use diffphys_ops::{stencil::Laplacian2, Boundary, Grid2, LinearOperator};
//! use ndarray::ArrayD;
//!
//! let grid = Grid2::new(8, 6, 1.0, 1.0, Boundary::ZeroDirichlet)?;
//! let a = Laplacian2::negative(grid);
//! let chol = SparseCholesky::new(&a, NullSpace::None)?;
//! let x_star = diffphys_tape::test_array::<f64>(&[8, 6], 1);
//! let b = a.apply(x_star.view())?;
//! let x = chol.solve(b.view())?;
//! assert!(x.iter().zip(&x_star).all(|(p, q)| (p - q).abs() < 1e-12));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # Singular operators
//!
//! An all-Neumann (closed) or periodic Laplacian has the constants in its
//! kernel, and Cholesky fails on it. With [`NullSpace::Constant`] (or
//! [`NullSpace::ConstantOn`] a mask of active cells) the reference solves for the
//! solution of zero mean: it removes the mean of `b` (making the system
//! consistent, `kᵀ b = 0`), pins one unknown `x_c = 0` by deleting row and column
//! `c`, factorises the remaining matrix, and removes the mean of the result.
//!
//! Why that is the same solution: if the kernel of `A` is exactly `span{k}` with
//! `k_c ≠ 0`, deleting row and column `c` leaves a positive definite matrix (a
//! vector `y` with `y_c = 0` and `yᵀ A y = 0` would lie in the kernel, so be a
//! multiple of `k`, so be zero). Its solution satisfies every equation but row
//! `c`; row `c` follows, because `kᵀ A = 0` and `kᵀ b = 0` make the residual
//! `k_c (A x − b)_c = −Σ_{i≠c} k_i (A x − b)_i = 0`. All solutions differ by
//! multiples of `k`, and removing the mean picks the one that CG returns.
//! After every solve the full residual is checked, so a wrongly declared null
//! space is an error rather than a wrong answer.
//!
//! # References
//! - T. A. Davis, *Direct Methods for Sparse Linear Systems*, SIAM 2006, ch. 4
//!   (sparse Cholesky).
//! - P. Bochev and R. B. Lehoucq, *On the finite element solution of the pure
//!   Neumann problem*, SIAM Review 47 (2005) 50–66 (pinning and its consistency).

use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};
use ndarray::{ArrayD, ArrayViewD, IxDyn};
use thiserror::Error;

use crate::cg::NullSpace;
use crate::{LinearOperator, OpsError};

/// Why the reference solve failed.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ReferenceError {
    /// The operator cannot list its nonzeros.
    #[error(
        "operator {operator} gives no triplets (LinearOperator::triplets); it cannot be assembled"
    )]
    NoTriplets {
        /// The operator's name.
        operator: String,
    },
    /// The operator is not square or does not declare itself symmetric.
    #[error("operator {operator} is not a symmetric square operator: {message}")]
    NotSymmetric {
        /// The operator's name.
        operator: String,
        /// What is wrong.
        message: String,
    },
    /// `b` does not have the operator's shape, or the null-space mask does not.
    #[error("shape mismatch in sparse_cholesky: {what} has shape {found:?}, the operator needs {expected:?}")]
    ShapeMismatch {
        /// Which array.
        what: String,
        /// The operator's shape.
        expected: Vec<usize>,
        /// The array's shape.
        found: Vec<usize>,
    },
    /// The factorisation met a non-positive pivot: the matrix (after pinning, for
    /// a declared null space) is not positive definite.
    #[error("sparse Cholesky failed: the matrix is not positive definite (non-positive pivot at column {pivot} of {n}; a singular operator needs its NullSpace)")]
    NotPositiveDefinite {
        /// The column of the failing pivot in the factorised (reordered, pinned) matrix.
        pivot: usize,
        /// The order of the factorised matrix.
        n: usize,
    },
    /// faer reported an error other than a pivot (allocation, index overflow).
    #[error("sparse Cholesky failed: {0}")]
    Faer(String),
    /// NaN or infinity in the matrix, in `b` or in the result.
    #[error("non-finite value in sparse_cholesky: {what}")]
    NonFinite {
        /// Which quantity.
        what: String,
    },
    /// The solve does not satisfy `A x = Π b`: the declared null space is not the
    /// operator's kernel (or the system is too ill-conditioned for f64).
    #[error("sparse_cholesky: relative residual {relative_residual:.3e} after the solve; the declared null space is not the kernel of the operator")]
    Inconsistent {
        /// `‖A x − Π b‖ / ‖Π b‖`.
        relative_residual: f64,
    },
}

/// A reference error as an operator error (so that `?` works in code returning
/// [`OpsError`]): shapes stay shapes, NaN stays [`OpsError::NonFinite`], the rest
/// becomes [`OpsError::InvalidArgument`] of `sparse_cholesky` with the message.
impl From<ReferenceError> for OpsError {
    fn from(e: ReferenceError) -> Self {
        const OP: &str = "sparse_cholesky";
        match e {
            ReferenceError::ShapeMismatch {
                expected, found, ..
            } => OpsError::shape(OP, &expected, &found),
            ReferenceError::NonFinite { what } => OpsError::NonFinite {
                op: OP.to_string(),
                what,
            },
            other => OpsError::invalid(OP, other.to_string()),
        }
    }
}

/// Relative residual above which a solve is declared inconsistent.
const CONSISTENCY_TOL: f64 = 1e-6;

/// The sparse Cholesky factorisation of a symmetric positive definite (or, with
/// a [`NullSpace`], semidefinite) operator, ready to solve `A x = b` for any
/// number of right-hand sides.
#[derive(Debug, Clone)]
pub struct SparseCholesky {
    llt: faer::sparse::linalg::solvers::Llt<usize, f64>,
    shape: Vec<usize>,
    /// The full matrix, for the residual check.
    triplets: Vec<(usize, usize, f64)>,
    null_space: NullSpace,
    /// `reduced[i]`: the row of unknown `i` in the factorised matrix (`None` for
    /// the pinned one).
    reduced: Vec<Option<usize>>,
}

impl SparseCholesky {
    /// Assembles `op` and factorises it.
    ///
    /// # Errors
    /// [`ReferenceError::NoTriplets`], [`ReferenceError::NotSymmetric`],
    /// [`ReferenceError::ShapeMismatch`] for a mask of the wrong shape,
    /// [`ReferenceError::NonFinite`] for a non-finite entry,
    /// [`ReferenceError::NotPositiveDefinite`] if the factorisation fails.
    pub fn new<A: LinearOperator<f64> + ?Sized>(
        op: &A,
        null_space: NullSpace,
    ) -> Result<Self, ReferenceError> {
        let shape = op.input_shape().to_vec();
        if op.output_shape() != shape.as_slice() || !op.is_symmetric() {
            return Err(ReferenceError::NotSymmetric {
                operator: op.name().to_string(),
                message: format!(
                    "maps {:?} to {:?}, is_symmetric() = {}",
                    shape,
                    op.output_shape(),
                    op.is_symmetric()
                ),
            });
        }
        let triplets = op.triplets().ok_or_else(|| ReferenceError::NoTriplets {
            operator: op.name().to_string(),
        })?;
        if triplets.iter().any(|t| !t.2.is_finite()) {
            return Err(ReferenceError::NonFinite {
                what: "a matrix entry".to_string(),
            });
        }
        let n: usize = shape.iter().product();
        let pin = match &null_space {
            NullSpace::None => None,
            NullSpace::Constant => Some(0),
            NullSpace::ConstantOn(mask) => {
                if mask.shape() != shape.as_slice() {
                    return Err(ReferenceError::ShapeMismatch {
                        what: "null-space mask".to_string(),
                        expected: shape,
                        found: mask.shape().to_vec(),
                    });
                }
                Some(mask.as_slice().iter().position(|&a| a).ok_or_else(|| {
                    ReferenceError::Faer("null-space mask has no active cell".to_string())
                })?)
            }
        };
        let mut reduced = Vec::with_capacity(n);
        let mut m = 0;
        for i in 0..n {
            if Some(i) == pin {
                reduced.push(None);
            } else {
                reduced.push(Some(m));
                m += 1;
            }
        }
        // The lower triangle of the pinned matrix (faer reads only that side).
        let lower: Vec<Triplet<usize, usize, f64>> = triplets
            .iter()
            .filter(|&&(r, c, _)| r >= c)
            .filter_map(|&(r, c, v)| Some(Triplet::new(reduced[r]?, reduced[c]?, v)))
            .collect();
        let mat = SparseColMat::<usize, f64>::try_new_from_triplets(m, m, &lower)
            .map_err(|e| ReferenceError::Faer(format!("{e:?}")))?;
        let llt = mat.sp_cholesky(Side::Lower).map_err(|e| match e {
            faer::sparse::linalg::LltError::Numeric(
                faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index },
            ) => ReferenceError::NotPositiveDefinite { pivot: index, n: m },
            other => ReferenceError::Faer(format!("{other:?}")),
        })?;
        Ok(SparseCholesky {
            llt,
            shape,
            triplets,
            null_space,
            reduced,
        })
    }

    /// The shape of `b` and `x`.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// `x = A⁻¹ b` (for a singular operator: the zero-mean solution of
    /// `A x = Π b`, see the module docs).
    ///
    /// # Errors
    /// [`ReferenceError::ShapeMismatch`], [`ReferenceError::NonFinite`] for NaN in
    /// `b` or the result, [`ReferenceError::Inconsistent`] if the residual check
    /// fails.
    pub fn solve(&self, b: ArrayViewD<'_, f64>) -> Result<ArrayD<f64>, ReferenceError> {
        if b.shape() != self.shape.as_slice() {
            return Err(ReferenceError::ShapeMismatch {
                what: "right-hand side b".to_string(),
                expected: self.shape.clone(),
                found: b.shape().to_vec(),
            });
        }
        if b.iter().any(|v| !v.is_finite()) {
            return Err(ReferenceError::NonFinite {
                what: "the right-hand side b".to_string(),
            });
        }
        let mut rhs: Vec<f64> = b.iter().copied().collect();
        self.project(&mut rhs);
        let m = self.reduced.iter().flatten().count();
        let mut col = Mat::<f64>::zeros(m, 1);
        for (i, r) in self.reduced.iter().enumerate() {
            if let Some(r) = r {
                col[(*r, 0)] = rhs[i];
            }
        }
        self.llt.solve_in_place(col.as_mut());
        let mut x: Vec<f64> = self
            .reduced
            .iter()
            .map(|r| r.map_or(0.0, |r| col[(r, 0)]))
            .collect();
        self.project(&mut x);
        if x.iter().any(|v| !v.is_finite()) {
            return Err(ReferenceError::NonFinite {
                what: "the solution".to_string(),
            });
        }
        self.check_residual(&x, &rhs)?;
        Ok(ArrayD::from_shape_vec(IxDyn(&self.shape), x).expect("length matches shape"))
    }

    /// Removes the component along the null space (the mean).
    fn project(&self, v: &mut [f64]) {
        match &self.null_space {
            NullSpace::Constant => {
                let mean = v.iter().sum::<f64>() / v.len() as f64;
                v.iter_mut().for_each(|x| *x -= mean);
            }
            NullSpace::ConstantOn(mask) => {
                let active = mask.as_slice();
                let sum: f64 = v.iter().zip(active).filter(|p| *p.1).map(|p| p.0).sum();
                let mean = sum / mask.active_count() as f64;
                v.iter_mut()
                    .zip(active)
                    .filter(|p| *p.1)
                    .for_each(|p| *p.0 -= mean);
            }
            _ => {}
        }
    }

    /// `‖A x − b‖ ≤ CONSISTENCY_TOL·‖b‖` (`b` already projected).
    fn check_residual(&self, x: &[f64], b: &[f64]) -> Result<(), ReferenceError> {
        let mut r: Vec<f64> = b.iter().map(|v| -v).collect();
        for &(i, j, v) in &self.triplets {
            r[i] += v * x[j];
        }
        let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let b_norm = norm(b);
        let rel = if b_norm > 0.0 {
            norm(&r) / b_norm
        } else {
            norm(&r)
        };
        if rel > CONSISTENCY_TOL || !rel.is_finite() {
            return Err(ReferenceError::Inconsistent {
                relative_residual: rel,
            });
        }
        Ok(())
    }
}

/// `x = A⁻¹ b` by sparse Cholesky in one call (factorise, solve).
///
/// # Errors
/// As [`SparseCholesky::new`] and [`SparseCholesky::solve`].
pub fn exact_solve<A: LinearOperator<f64> + ?Sized>(
    op: &A,
    b: ArrayViewD<'_, f64>,
    null_space: NullSpace,
) -> Result<ArrayD<f64>, ReferenceError> {
    SparseCholesky::new(op, null_space)?.solve(b)
}
