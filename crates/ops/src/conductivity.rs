//! The variable-coefficient Laplacian `A(k) x = −∇·(k ∇x)` with a conductivity
//! `k` per cell, and its Poisson solve differentiated with respect to both the
//! right-hand side and the coefficient field.
//!
//! Solving `A(k) p = b` for a loss `L(p)`, the implicit function theorem gives,
//! with one adjoint solve `A(k) λ = ∂L/∂p` (`A` symmetric):
//!
//! ```text
//! forward:  p = A(k)⁻¹ b
//! adjoint:  λ = A(k)⁻¹ ∂L/∂p
//!           ∂L/∂b = λ
//!           ∂L/∂k = −λᵀ (∂A/∂k) p
//! ```
//!
//! The last line differentiates `A(k) p(k) = b`: `(∂A/∂k) p + A ∂p/∂k = 0`.
//! With the operator written over faces (see [`Conductivity2`]),
//! `λᵀ A(k) p = Σ_f w_f(k) (δ_f λ)(δ_f p)`, so `∂L/∂k_c` is a sum over the faces
//! of cell `c`: no matrix is formed, and the cost is one stencil pass after the
//! adjoint solve. Nothing of the CG iterates is kept.
//!
//! ```
//! use std::sync::Arc;
//! use diffphys_ops::cg::CgParams;
//! use diffphys_ops::conductivity::ConductivitySolve;
//! use diffphys_ops::{Boundary, Grid2};
//! use diffphys_tape::Tape;
//!
//! let grid = Grid2::square(8, 8, 1.0 / 8.0, Boundary::ZeroDirichlet)?;
//! let tape = Tape::<f64>::new();
//! let b = tape.constant(ndarray::ArrayD::ones(vec![8, 8]));
//! let k = tape.var(ndarray::ArrayD::from_elem(vec![8, 8], 2.0));
//! let p = tape.apply(ConductivitySolve::new(grid, CgParams::default()), &[b, k])?;
//! let loss = p.sum()?;
//! let grads = tape.backward(loss, &[k])?;
//! // A higher conductivity lowers the potential everywhere: ∂L/∂k < 0.
//! assert!(grads.get(k).unwrap().iter().all(|&g| g < 0.0));
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```
//!
//! # References
//! - M. B. Giles and N. A. Pierce, *An introduction to the adjoint approach to
//!   design*, Flow, Turbulence and Combustion 65 (2000) 393–415.
//! - C. R. Vogel, *Computational Methods for Inverse Problems*, SIAM 2002, ch. 1
//!   and 8 (the inverse conductivity problem, Tikhonov regularisation).

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{ArrayView2, IxDyn};

use crate::cg::{conjugate_gradient, CgInfo, CgParams};
use crate::linear::wide;
use crate::poisson::SolveLog;
use crate::stencil::push_row;
use crate::{Boundary, Grid2, LinearOperator, OpsError, Result};

const OP: &str = "conductivity";

/// One face of the grid: the cells on its low and high side (`None` beyond a
/// zero-Dirichlet wall, where the value is zero), and `∂w/∂k` for each of them.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Face {
    lo: Option<usize>,
    hi: Option<usize>,
    dw_dk: f64,
}

impl Face {
    /// `δ x = x_hi − x_lo` (a missing side reads 0).
    #[inline]
    fn jump<T: Real>(&self, x: &[T]) -> T {
        let at = |c: Option<usize>| c.map_or(T::zero(), |i| x[i]);
        at(self.hi) - at(self.lo)
    }

    fn cells(&self) -> impl Iterator<Item = usize> {
        self.lo.into_iter().chain(self.hi)
    }
}

/// `A(k) x = −∇·(k ∇x)` on a cell-centred [`Grid2`] with a conductivity `k > 0`
/// per cell, by finite volumes over faces:
///
/// ```text
/// (A x)_c = Σ_{faces f of c} w_f · (x_c − x_neighbour),
/// w_f = (k_lo + k_hi) / (2h²)     between two cells (h = dx or dy),
/// w_f = 2 k_c / h²                at a zero-Dirichlet wall (neighbour value 0),
/// w_f = 0                         at a closed wall (zero flux).
/// ```
///
/// Equivalently `A = Σ_f w_f d_f d_fᵀ` with `d_f = e_hi − e_lo`: symmetric, so
/// the adjoint is the operator itself (`Aᵀ = A`); positive definite with a
/// zero-Dirichlet wall, positive semidefinite with constants in its kernel with
/// closed walls all round. For `k ≡ 1` it is, entry by entry,
/// [`crate::stencil::Laplacian2::negative`].
///
/// The derivative in the coefficients is `∂(λᵀ A x)/∂k_c = Σ_{f ∋ c}
/// (∂w_f/∂k_c) (δ_f λ)(δ_f x)` with `δ_f x = x_hi − x_lo`
/// ([`Conductivity2::coefficient_vjp`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Conductivity2 {
    grid: Grid2,
    shape: [usize; 2],
    faces: Vec<Face>,
    /// `w_f`, one per face.
    weights: Vec<f64>,
}

impl Conductivity2 {
    /// The operator on `grid` with conductivity `k` (shape `[nx, ny]`).
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] for a `k` of another shape,
    /// [`OpsError::NonFinite`] for NaN or infinity in `k`,
    /// [`OpsError::InvalidArgument`] for a `k ≤ 0` (the operator would not be
    /// positive (semi)definite) or a periodic boundary (not supported).
    pub fn new<T: Real>(grid: Grid2, k: ArrayView2<'_, T>) -> Result<Self> {
        let shape = grid.shape();
        if k.shape() != shape {
            return Err(OpsError::shape(OP, &shape, k.shape()));
        }
        for b in [grid.boundary_x, grid.boundary_y] {
            if b == Boundary::Periodic {
                return Err(OpsError::invalid(
                    OP,
                    "periodic boundaries are not supported; use ZeroDirichlet or Closed",
                ));
            }
        }
        let k: Vec<f64> = k.iter().map(|v| v.as_f64()).collect();
        if let Some(bad) = k.iter().find(|v| !v.is_finite()) {
            return Err(OpsError::NonFinite {
                op: OP.to_string(),
                what: format!("conductivity k (value {bad})"),
            });
        }
        if let Some((c, bad)) = k.iter().enumerate().find(|(_, v)| **v <= 0.0) {
            return Err(OpsError::invalid(
                OP,
                format!(
                    "conductivity must be positive, got k = {bad:e} at cell ({}, {})",
                    c / shape[1],
                    c % shape[1]
                ),
            ));
        }
        let faces = faces(&grid);
        let weights = faces
            .iter()
            .map(|f| f.dw_dk * f.cells().map(|c| k[c]).sum::<f64>())
            .collect();
        Ok(Conductivity2 {
            grid,
            shape,
            faces,
            weights,
        })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid2 {
        &self.grid
    }

    /// `∂(λᵀ A(k) x)/∂k` (shape `[nx, ny]`): the derivative of the bilinear form
    /// in the conductivity of each cell, `Σ_{f ∋ c} (∂w_f/∂k_c)(δ_f λ)(δ_f x)`.
    /// The gradient of a loss through `p = A(k)⁻¹ b` is minus this at `x = p`
    /// and `λ = A⁻¹ ∂L/∂p`.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if `x` or `lambda` is not of the grid's shape.
    pub fn coefficient_vjp<T: Real>(
        &self,
        x: ArrayViewD<'_, T>,
        lambda: ArrayViewD<'_, T>,
    ) -> Result<ArrayD<T>> {
        for a in [&x, &lambda] {
            if a.shape() != self.shape {
                return Err(OpsError::shape(OP, &self.shape, a.shape()));
            }
        }
        let (x, l) = (x.as_standard_layout(), lambda.as_standard_layout());
        let (xs, ls) = (x.as_slice().unwrap(), l.as_slice().unwrap());
        let mut g = vec![0.0; xs.len()];
        for f in &self.faces {
            let s = f.dw_dk * wide(f.jump(ls)) * wide(f.jump(xs));
            for c in f.cells() {
                g[c] += s;
            }
        }
        Ok(
            ArrayD::from_shape_vec(IxDyn(&self.shape), g.into_iter().map(T::from_f64).collect())
                .expect("one per cell"),
        )
    }

    /// `out = A x` on row-major slices, returning `<x, A x>` in f64.
    fn run<T: Real>(&self, x: &[T], out: &mut [T]) -> f64 {
        out.fill(T::zero());
        let mut dot = 0.0;
        for (f, &w) in self.faces.iter().zip(&self.weights) {
            let jump = f.jump(x);
            let flux = T::from_f64(w) * jump;
            if let Some(i) = f.lo {
                out[i] -= flux;
            }
            if let Some(i) = f.hi {
                out[i] += flux;
            }
            // <x, A x> = Σ_f w_f (δ_f x)².
            dot += w * wide(jump) * wide(jump);
        }
        dot
    }

    fn apply_slices<T: Real>(
        &self,
        x: ArrayViewD<'_, T>,
        out: ndarray::ArrayViewMutD<'_, T>,
    ) -> f64 {
        crate::stencil::with_slices(x, out, |x, o| self.run(x, o))
    }
}

/// The faces of `grid` that carry flux, x-faces first: interior faces between
/// two cells, and zero-Dirichlet wall faces (closed walls carry none).
fn faces(grid: &Grid2) -> Vec<Face> {
    let (nx, ny) = (grid.nx, grid.ny);
    let mut faces = Vec::with_capacity(2 * (nx + 1) * (ny + 1));
    // One axis: faces 0..=n between cells i − 1 and i, of spacing h.
    let axis =
        |n: usize, h: f64, b: Boundary, cell: &dyn Fn(usize) -> usize, out: &mut Vec<Face>| {
            let interior = 0.5 / (h * h);
            let wall = 2.0 / (h * h);
            for i in 0..=n {
                let (lo, hi) = (i.checked_sub(1).map(cell), (i < n).then(|| cell(i)));
                match (lo, hi) {
                    (Some(_), Some(_)) => out.push(Face {
                        lo,
                        hi,
                        dw_dk: interior,
                    }),
                    _ if b == Boundary::ZeroDirichlet => out.push(Face {
                        lo,
                        hi,
                        dw_dk: wall,
                    }),
                    _ => {}
                }
            }
        };
    for j in 0..ny {
        axis(nx, grid.dx, grid.boundary_x, &|i| i * ny + j, &mut faces);
    }
    for i in 0..nx {
        axis(ny, grid.dy, grid.boundary_y, &|j| i * ny + j, &mut faces);
    }
    faces
}

impl<T: Real> LinearOperator<T> for Conductivity2 {
    fn name(&self) -> &str {
        OP
    }
    fn input_shape(&self) -> &[usize] {
        &self.shape
    }
    fn output_shape(&self) -> &[usize] {
        &self.shape
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ndarray::ArrayViewMutD<'_, T>) {
        self.apply_slices(x, out);
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ndarray::ArrayViewMutD<'_, T>) {
        self.apply_slices(y, out);
    }
    fn apply_into_dot(&self, x: ArrayViewD<'_, T>, out: ndarray::ArrayViewMutD<'_, T>) -> f64 {
        self.apply_slices(x, out)
    }
    fn is_symmetric(&self) -> bool {
        true
    }
    fn diagonal(&self) -> Option<ArrayD<T>> {
        let mut d = vec![0.0; self.shape[0] * self.shape[1]];
        for (f, &w) in self.faces.iter().zip(&self.weights) {
            for c in f.cells() {
                d[c] += w;
            }
        }
        Some(
            ArrayD::from_shape_vec(IxDyn(&self.shape), d.into_iter().map(T::from_f64).collect())
                .expect("one per cell"),
        )
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        let n = self.shape[0] * self.shape[1];
        let mut rows: Vec<Vec<(usize, f64)>> = (0..n).map(|c| vec![(c, 0.0)]).collect();
        for (f, &w) in self.faces.iter().zip(&self.weights) {
            for c in f.cells() {
                rows[c].push((c, w));
            }
            if let (Some(a), Some(b)) = (f.lo, f.hi) {
                rows[a].push((b, -w));
                rows[b].push((a, -w));
            }
        }
        let mut t = Vec::new();
        for (r, entries) in rows.iter_mut().enumerate() {
            push_row(&mut t, r, entries);
        }
        Some(t)
    }
}

/// `p = A(k)⁻¹ b` by conjugate gradient from zero (with a null space in
/// `params` for closed walls: the zero-mean solution of `A p = Π b`).
///
/// # Errors
/// As [`Conductivity2::new`] for `k`; the [`crate::cg::CgError`] of the solve
/// as [`OpsError::Cg`].
pub fn conductivity_solve<T: Real>(
    grid: Grid2,
    k: ArrayView2<'_, T>,
    b: ArrayViewD<'_, T>,
    params: &CgParams,
) -> Result<(ArrayD<T>, CgInfo)> {
    let a = Conductivity2::new(grid, k)?;
    let mut p = ArrayD::zeros(IxDyn(&a.shape));
    let info = conjugate_gradient(&a, b, p.view_mut(), params)?;
    Ok((p, info))
}

/// The gradients of [`conductivity_solve`] given `grad_p = ∂L/∂p` at its
/// solution `p`: one adjoint solve `λ = A(k)⁻¹ grad_p`, then `∂L/∂b = λ` and
/// `∂L/∂k = −λᵀ (∂A/∂k) p` ([`Conductivity2::coefficient_vjp`]). Returns
/// `(∂L/∂b, ∂L/∂k, info of the adjoint solve)`; `∂L/∂k` only if `want_k`.
///
/// # Errors
/// As [`conductivity_solve`], and [`OpsError::ShapeMismatch`] for `p` or
/// `grad_p`.
pub fn conductivity_solve_vjp<T: Real>(
    a: &Conductivity2,
    p: ArrayViewD<'_, T>,
    grad_p: ArrayViewD<'_, T>,
    params: &CgParams,
    want_k: bool,
) -> Result<(ArrayD<T>, Option<ArrayD<T>>, CgInfo)> {
    let mut lambda = ArrayD::zeros(IxDyn(&a.shape));
    let info = conjugate_gradient(a, grad_p, lambda.view_mut(), params)?;
    let grad_k = if want_k {
        Some(a.coefficient_vjp(p, lambda.view())?.mapv(|v| -v))
    } else {
        None
    };
    Ok((lambda, grad_k, info))
}

const SOLVE: &str = "conductivity_solve";

/// The Poisson solve `p = A(k)⁻¹ b` of the variable-coefficient Laplacian
/// ([`Conductivity2`]) as a tape op with inputs `[b, k]`: forward by CG,
/// backward by one adjoint CG solve, giving `∂L/∂b = λ` and
/// `∂L/∂k = −λᵀ (∂A/∂k) p` (see the module docs), each only if asked for.
///
/// The backward reads `k` and `p` from the tape and rebuilds the operator; the
/// op keeps nothing else ([`Op::saved_bytes`] is 0). Solves are recorded in a
/// [`SolveLog`], shared by every clone (no warm starts: a clone shares only
/// the counts). Recorded with `tape.apply(solve, &[b, k])`. Errors surface as
/// [`TapeError::Op`] named `conductivity_solve`, with the [`OpsError`] as
/// its cause.
#[derive(Debug, Clone)]
pub struct ConductivitySolve<T> {
    grid: Grid2,
    forward: CgParams,
    adjoint: CgParams,
    log: SolveLog<T>,
}

impl<T: Real> ConductivitySolve<T> {
    /// The solve on `grid` with `params` for the forward and the adjoint solve.
    pub fn new(grid: Grid2, params: CgParams) -> Self {
        ConductivitySolve {
            grid,
            adjoint: params.clone(),
            forward: params,
            log: SolveLog::new(),
        }
    }

    /// With other parameters for the adjoint solve.
    pub fn with_adjoint_params(mut self, params: CgParams) -> Self {
        self.adjoint = params;
        self
    }

    /// A handle on the log of the solves.
    pub fn log(&self) -> SolveLog<T> {
        self.log.clone()
    }

    fn operator(&self, k: &ArrayViewD<'_, T>) -> Result<Conductivity2> {
        let k = k
            .view()
            .into_dimensionality()
            .map_err(|_| OpsError::shape(SOLVE, &self.grid.shape(), k.shape()))?;
        Conductivity2::new(self.grid, k)
    }
}

impl<T: Real> Op<T> for ConductivitySolve<T> {
    fn name(&self) -> &str {
        SOLVE
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        if inputs.len() != 2 {
            return Err(TapeError::Arity {
                op: SOLVE.to_string(),
                expected: 2,
                found: inputs.len(),
            });
        }
        let a = self.operator(&inputs[1]).map_err(|e| {
            let kind = e.kind();
            TapeError::op_of_kind(SOLVE, e, kind)
        })?;
        if inputs[0].shape() != a.shape {
            return Err(TapeError::shape(SOLVE, &a.shape, inputs[0].shape()));
        }
        let mut p = ArrayD::zeros(IxDyn(&a.shape));
        let info =
            conjugate_gradient(&a, inputs[0].view(), p.view_mut(), &self.forward).map_err(|e| {
                let kind = e.kind();
                TapeError::op_of_kind(SOLVE, OpsError::Cg(e), kind)
            })?;
        self.log.record_forward(&info, &p, false);
        Ok(vec![p])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        if !(args.needs(0) || args.needs(1)) {
            return Ok(vec![None, None]);
        }
        let a = self.operator(args.input(1)).map_err(|e| {
            let kind = e.kind();
            TapeError::op_of_kind(SOLVE, e, kind)
        })?;
        let (lambda, grad_k, info) = conductivity_solve_vjp(
            &a,
            args.output(0).view(),
            args.grad_out().view(),
            &self.adjoint,
            args.needs(1),
        )
        .map_err(|e| {
            let kind = e.kind();
            TapeError::op_of_kind(SOLVE, e, kind)
        })?;
        self.log.record_adjoint(&info, &lambda, false);
        Ok(vec![args.needs(0).then_some(lambda), grad_k])
    }
}
