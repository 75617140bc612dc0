//! The implicit Poisson solve `p = A⁻¹ b`, `A = −∇²` (5-point), and its
//! vector–Jacobian product `grad_b = A⁻¹ grad_p` (one more solve, `A = Aᵀ`).

use diffphys_ops::cg::NullSpace;
use diffphys_ops::multigrid::Multigrid;
use diffphys_ops::poisson::{poisson_solve, poisson_solve_vjp};
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::Boundary;
use diffphys_tape::Real;
use numpy::Element;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::arrays::{dtype_of, grid2, to_numpy, view, BoundaryArg, Dtype};
use crate::errors::check;
use crate::solver::{info_dict, Kind, Options, Params};

/// The Poisson solve on one grid: `p = A⁻¹ b` with `A = −∇²` (the 5-point
/// Laplacian with the grid's boundaries) by conjugate gradient, multigrid-
/// preconditioned by default. With no zero-Dirichlet axis `A` is singular and
/// the solve returns the zero-mean solution of `A p = Π b` (`Π` removes the
/// mean); its adjoint is the same projected solve.
///
/// Adjoint (implicit, by the implicit function theorem): `grad_b = A⁻ᵀ grad_p
/// = A⁻¹ grad_p`, one solve with the same operator, nothing of the forward
/// iterations kept.
///
/// Constructor: `Poisson(shape, *, spacing=(1.0, 1.0), boundary="dirichlet",
/// preconditioner="multigrid", rel_tol=None, abs_tol=0.0, max_iters=None,
/// sweeps=2, adjoint_rel_tol=None, iterations=None)`; `rel_tol` None is 1e-10 for float64
/// arrays and 1e-5 for float32 ones.
///
/// Shapes and dtypes: `b`, `p`, `grad_p` and `grad_b` are `(nx, ny)` numpy
/// arrays of float32 or float64 (the result has the input's dtype).
///
/// Raises: `InvalidArgumentError` (unknown boundary or preconditioner, a
/// negative or non-finite tolerance, `iterations` with a tolerance),
/// `ShapeError` (an array not of `shape`), `TypeError` (not a float32 or
/// float64 array), `NonFiniteError` (NaN or infinity in the input or the
/// result), `NotConvergedError` (no convergence within `max_iters`).
///
/// >>> import numpy as np, diffphys as dp
/// >>> p = dp.Poisson((32, 32), spacing=(1 / 32, 1 / 32)).solve(np.ones((32, 32)))
#[pyclass(module = "diffphys._native", frozen)]
pub struct Poisson {
    op: Laplacian2,
    params: Params,
    shape: [usize; 2],
}

#[pymethods]
impl Poisson {
    /// The constructor (its arguments are described on the class).
    #[new]
    #[pyo3(signature = (
        shape, *, spacing = (1.0, 1.0), boundary = BoundaryArg::both("dirichlet"),
        preconditioner = "multigrid", rel_tol = None, abs_tol = 0.0, max_iters = None,
        sweeps = 2, adjoint_rel_tol = None, iterations = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        shape: (usize, usize),
        spacing: (f64, f64),
        boundary: BoundaryArg,
        preconditioner: &str,
        rel_tol: Option<f64>,
        abs_tol: f64,
        max_iters: Option<usize>,
        sweeps: usize,
        adjoint_rel_tol: Option<f64>,
        iterations: Option<usize>,
    ) -> PyResult<Self> {
        let shape = [shape.0, shape.1];
        let grid = grid2(shape, spacing, &boundary)?;
        let options = Options {
            preconditioner: Kind::parse(preconditioner)?,
            rel_tol,
            abs_tol,
            max_iters,
            sweeps,
            adjoint_rel_tol,
            iterations,
        };
        let mut params = options.params(|s| Multigrid::new(&grid, s))?;
        let dirichlet = Boundary::ZeroDirichlet;
        if grid.boundary_x != dirichlet && grid.boundary_y != dirichlet {
            params = params.map(|p| p.with_null_space(NullSpace::Constant));
        }
        Ok(Poisson {
            op: Laplacian2::negative(grid),
            params,
            shape,
        })
    }

    /// The grid's cell counts `(nx, ny)`.
    #[getter]
    fn shape(&self) -> (usize, usize) {
        (self.shape[0], self.shape[1])
    }

    /// `p = A⁻¹ b` (`b`: `(nx, ny)`, float32 or float64; `p` of the same
    /// shape and dtype); with `return_info`, `(p, info)` where `info` is a
    /// dict of `iterations`, `relative_residual` and `converged`.
    ///
    /// Raises `ShapeError`, `TypeError`, `NonFiniteError`,
    /// `NotConvergedError`.
    #[pyo3(signature = (b, *, return_info = false))]
    fn solve<'py>(&self, b: &Bound<'py, PyAny>, return_info: bool) -> PyResult<Bound<'py, PyAny>> {
        match dtype_of(b, "b")? {
            Dtype::F32 => self.run::<f32>(b, "b", false, return_info),
            Dtype::F64 => self.run::<f64>(b, "b", false, return_info),
        }
    }

    /// `grad_b = A⁻¹ grad_p` (the vector–Jacobian product of `solve`;
    /// `grad_p`: `(nx, ny)`, float32 or float64); `return_info` as for
    /// `solve`.
    ///
    /// Raises `ShapeError`, `TypeError`, `NonFiniteError`,
    /// `NotConvergedError`.
    #[pyo3(signature = (grad_p, *, return_info = false))]
    fn vjp<'py>(
        &self,
        grad_p: &Bound<'py, PyAny>,
        return_info: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        match dtype_of(grad_p, "grad_p")? {
            Dtype::F32 => self.run::<f32>(grad_p, "grad_p", true, return_info),
            Dtype::F64 => self.run::<f64>(grad_p, "grad_p", true, return_info),
        }
    }
}

impl Poisson {
    /// One solve of `rhs` (forward or adjoint) with the GIL released.
    fn run<'py, T: Real + Element>(
        &self,
        rhs: &Bound<'py, PyAny>,
        what: &str,
        adjoint: bool,
        return_info: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let py = rhs.py();
        let rhs = view::<T>(rhs, what)?;
        let v = rhs.as_array();
        let (forward, backward) = self.params.of::<T>();
        let (x, info) = check(py.detach(|| {
            if adjoint {
                poisson_solve_vjp(&self.op, v, backward, None)
            } else {
                poisson_solve(&self.op, v, forward)
            }
        }))?;
        let x = to_numpy(py, x);
        if return_info {
            Ok(PyTuple::new(py, [x, info_dict(py, &info)?.into_any()])?.into_any())
        } else {
            Ok(x)
        }
    }
}
