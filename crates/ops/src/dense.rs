//! A dense matrix as a [`LinearOperator`]: the operator of small tests and
//! manufactured solutions, where every entry is known.
//!
//! ```
//! use diffphys_ops::{dense::DenseOperator, LinearOperator};
//! use ndarray::{arr1, arr2};
//!
//! let a = DenseOperator::new(arr2(&[[2.0, 1.0], [1.0, 3.0]]));
//! assert!(LinearOperator::<f64>::is_symmetric(&a));
//! let ax = a.apply(arr1(&[1.0, -1.0]).into_dyn().view())?;
//! assert_eq!(ax.as_slice().unwrap(), &[1.0, -2.0]);
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```

use diffphys_tape::Real;
use ndarray::{Array1, Array2, ArrayD, ArrayView2, ArrayViewD, ArrayViewMutD, IxDyn};

use crate::{LinearOperator, OpsError, Result};

/// `y = M x` for a dense `m × n` matrix `M`, on fields of any shapes with `n` and
/// `m` entries (flattened in row-major order). Adjoint: `Mᵀ`.
///
/// [`LinearOperator::is_symmetric`] is true only if `M` is square and exactly
/// equal to its transpose; [`LinearOperator::diagonal`] and
/// [`LinearOperator::triplets`] (the nonzeros) are available for square `M`.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseOperator<T> {
    matrix: Array2<T>,
    input: Vec<usize>,
    output: Vec<usize>,
    symmetric: bool,
}

impl<T: Real> DenseOperator<T> {
    /// The matrix `M` mapping vectors of shape `[ncols]` to `[nrows]`.
    pub fn new(matrix: Array2<T>) -> Self {
        let (m, n) = matrix.dim();
        let symmetric = m == n && matrix == matrix.t();
        DenseOperator {
            matrix: matrix.as_standard_layout().into_owned(),
            input: vec![n],
            output: vec![m],
            symmetric,
        }
    }

    /// `M` mapping fields of `input_shape` to fields of `output_shape` (a 2D
    /// field of shape `[nx, ny]` as the vector of its row-major entries).
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if the shapes do not hold `ncols` and `nrows`
    /// entries.
    pub fn with_shapes(
        matrix: Array2<T>,
        input_shape: &[usize],
        output_shape: &[usize],
    ) -> Result<Self> {
        let (m, n) = matrix.dim();
        if input_shape.iter().product::<usize>() != n {
            return Err(OpsError::shape("dense", &[n], input_shape));
        }
        if output_shape.iter().product::<usize>() != m {
            return Err(OpsError::shape("dense", &[m], output_shape));
        }
        let mut op = Self::new(matrix);
        op.input = input_shape.to_vec();
        op.output = output_shape.to_vec();
        op.symmetric &= input_shape == output_shape;
        Ok(op)
    }

    /// The symmetric matrix `Q diag(λ) Qᵀ` with the given eigenvalues, `Q` an
    /// orthogonal matrix (a product of two Householder reflections with seeded
    /// pseudo-random vectors). Built in `f64` and rounded to `T`, then
    /// symmetrised exactly. Positive eigenvalues give an SPD test matrix of known
    /// condition number `max λ / min λ`; a zero or negative one, a semidefinite or
    /// indefinite one.
    pub fn with_spectrum(eigenvalues: &[f64], seed: u64) -> Self {
        let n = eigenvalues.len();
        let mut a = Array2::<f64>::from_diag(&Array1::from(eigenvalues.to_vec()));
        for k in 0..2 {
            let v = diffphys_tape::test_array::<f64>(&[n], seed.wrapping_add(k));
            let vv: f64 = v.iter().map(|x| x * x).sum();
            if vv == 0.0 {
                continue;
            }
            // H = I − 2 v vᵀ / (vᵀ v); A ← H A H.
            let h = Array2::from_shape_fn((n, n), |(i, j)| {
                f64::from(u8::from(i == j)) - 2.0 * v[i] * v[j] / vv
            });
            a = h.dot(&a).dot(&h);
        }
        let sym = Array2::from_shape_fn((n, n), |(i, j)| 0.5 * (a[[i, j]] + a[[j, i]]));
        Self::new(sym.mapv(T::from_f64))
    }

    /// The matrix.
    pub fn matrix(&self) -> ArrayView2<'_, T> {
        self.matrix.view()
    }

    fn multiply(m: ArrayView2<'_, T>, x: ArrayViewD<'_, T>, mut out: ArrayViewMutD<'_, T>) {
        let x = x.as_standard_layout();
        let xs = x.as_slice().expect("standard layout is contiguous");
        for (o, row) in out.iter_mut().zip(m.rows()) {
            *o = row
                .iter()
                .zip(xs)
                .fold(T::zero(), |acc, (&a, &b)| acc + a * b);
        }
    }
}

impl<T: Real> LinearOperator<T> for DenseOperator<T> {
    fn name(&self) -> &str {
        "dense"
    }
    fn input_shape(&self) -> &[usize] {
        &self.input
    }
    fn output_shape(&self) -> &[usize] {
        &self.output
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        Self::multiply(self.matrix.view(), x, out);
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        Self::multiply(self.matrix.t(), y, out);
    }
    fn is_symmetric(&self) -> bool {
        self.symmetric
    }
    fn diagonal(&self) -> Option<ArrayD<T>> {
        if self.input != self.output {
            return None;
        }
        let d = self.matrix.diag().to_owned();
        d.into_shape_with_order(IxDyn(&self.output)).ok()
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        Some(
            self.matrix
                .indexed_iter()
                .filter(|&((i, j), v)| *v != T::zero() || i == j)
                .map(|((i, j), &v)| (i, j, v))
                .collect(),
        )
    }
}
