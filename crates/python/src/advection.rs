//! Semi-Lagrangian and first-order upwind advection of a cell-centred field by
//! a cell-centred velocity on a 2D grid, and their vector–Jacobian products.

use diffphys_ops::advection::{self as ops, AdvectionParams, Wants};
use diffphys_ops::Grid2;
use diffphys_tape::Real;
use numpy::{Element, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::arrays::{dtype_of, grid2, shape2, to_numpy, view, BoundaryArg, Dtype};
use crate::errors::{check, ShapeError};

/// Which scheme a call runs.
#[derive(Debug, Clone, Copy)]
enum Scheme {
    SemiLagrangian,
    Upwind { allow_cfl_violation: bool },
}

/// The field `d` (`[nx, ny]`), the velocity `u` (`[2, nx, ny]`) and the grid.
struct Inputs<'py, T: Element> {
    d: PyReadonlyArrayDyn<'py, T>,
    u: PyReadonlyArrayDyn<'py, T>,
    grid: Grid2,
}

fn inputs<'py, T: Element>(
    d: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
    spacing: (f64, f64),
    boundary: &BoundaryArg,
) -> PyResult<Inputs<'py, T>> {
    let (d, u) = (view::<T>(d, "d")?, view::<T>(u, "u")?);
    let [nx, ny] = shape2(&d, "d")?;
    if u.shape() != [2, nx, ny] {
        return Err(ShapeError::new_err(format!(
            "shape mismatch in advection: u has shape {:?}, d of shape {:?} needs [2, {nx}, {ny}]",
            u.shape(),
            [nx, ny]
        )));
    }
    let grid = grid2([nx, ny], spacing, boundary)?;
    Ok(Inputs { d, u, grid })
}

fn forward_t<'py, T: Real + Element>(
    d: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
    dt: f64,
    spacing: (f64, f64),
    boundary: &BoundaryArg,
    scheme: Scheme,
) -> PyResult<Bound<'py, PyAny>> {
    let py = d.py();
    let x = inputs::<T>(d, u, spacing, boundary)?;
    let dv = x.d.as_array().into_dimensionality().expect("checked 2D");
    let uv = x.u.as_array().into_dimensionality().expect("checked 3D");
    let grid = x.grid;
    let out = check(py.detach(|| match scheme {
        Scheme::SemiLagrangian => ops::semi_lagrangian2(&grid, dt, dv, uv),
        Scheme::Upwind {
            allow_cfl_violation,
        } => ops::upwind2(&grid, &params(dt, allow_cfl_violation), dv, uv),
    }))?;
    Ok(to_numpy(py, out))
}

#[allow(clippy::too_many_arguments)]
fn vjp_t<'py, T: Real + Element>(
    d: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
    grad_out: &Bound<'py, PyAny>,
    dt: f64,
    spacing: (f64, f64),
    boundary: &BoundaryArg,
    scheme: Scheme,
) -> PyResult<Bound<'py, PyTuple>> {
    let py = d.py();
    let x = inputs::<T>(d, u, spacing, boundary)?;
    let g = view::<T>(grad_out, "grad_out")?;
    if g.shape() != x.d.shape() {
        return Err(ShapeError::new_err(format!(
            "shape mismatch in advection: grad_out has shape {:?}, d has {:?}",
            g.shape(),
            x.d.shape()
        )));
    }
    let dv = x.d.as_array().into_dimensionality().expect("checked 2D");
    let uv = x.u.as_array().into_dimensionality().expect("checked 3D");
    let gv = g.as_array().into_dimensionality().expect("checked 2D");
    let grid = x.grid;
    let grads = check(py.detach(|| match scheme {
        Scheme::SemiLagrangian => ops::semi_lagrangian2_vjp(&grid, dt, dv, uv, gv, Wants::BOTH),
        Scheme::Upwind {
            allow_cfl_violation,
        } => ops::upwind2_vjp(
            &grid,
            &params(dt, allow_cfl_violation),
            dv,
            uv,
            gv,
            Wants::BOTH,
        ),
    }))?;
    let field = grads.field.expect("asked for");
    let velocity = grads.velocity.expect("asked for");
    PyTuple::new(py, [to_numpy(py, field), to_numpy(py, velocity)])
}

fn params(dt: f64, allow_cfl_violation: bool) -> AdvectionParams {
    let p = AdvectionParams::new(dt);
    if allow_cfl_violation {
        p.allowing_cfl_violation()
    } else {
        p
    }
}

/// `semi_lagrangian2(d, u, *, dt, spacing=(1.0, 1.0), boundary="periodic")`:
/// one semi-Lagrangian step, `d'(x) = d(x − u(x)·dt)` with bilinear
/// interpolation at the departure point.
///
/// Shapes and dtypes: `d` is `(nx, ny)` (cell-centred), `u` is `(2, nx, ny)`
/// (`u[0]` along x, `u[1]` along y, cell-centred), both float32 or float64 of
/// one dtype; the result has `d`'s shape and dtype. `spacing` is `(dx, dy)`,
/// `boundary` `"periodic"`, `"dirichlet"`, `"closed"` or a pair per axis.
///
/// Raises `ShapeError` (`u` not `(2, nx, ny)`), `TypeError` (not float
/// arrays, or of two dtypes), `InvalidArgumentError` (`dt` or the spacing
/// not positive, an unknown boundary), `NonFiniteError`.
#[pyfunction]
#[pyo3(signature = (d, u, *, dt, spacing = (1.0, 1.0), boundary = BoundaryArg::both("periodic")))]
pub(crate) fn semi_lagrangian2<'py>(
    d: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
    dt: f64,
    spacing: (f64, f64),
    boundary: BoundaryArg,
) -> PyResult<Bound<'py, PyAny>> {
    let s = Scheme::SemiLagrangian;
    match dtype_of(d, "d")? {
        Dtype::F32 => forward_t::<f32>(d, u, dt, spacing, &boundary, s),
        Dtype::F64 => forward_t::<f64>(d, u, dt, spacing, &boundary, s),
    }
}

/// `semi_lagrangian2_vjp(d, u, grad_out, *, dt, spacing, boundary)`:
/// `(∂L/∂d, ∂L/∂u)` of `semi_lagrangian2`: `∂L/∂d` scatters `grad_out`
/// back through the bilinear weights, `∂L/∂u` is `grad_out` times the
/// bilinear slope of `d` at the departure point times `−dt`.
///
/// Shapes and dtypes: as `semi_lagrangian2` (float32 or float64), `grad_out`
/// of `d`'s shape; returns arrays of `d`'s and `u`'s shapes. Raises as
/// `semi_lagrangian2` (`ShapeError` also for `grad_out`).
#[pyfunction]
#[pyo3(signature = (d, u, grad_out, *, dt, spacing = (1.0, 1.0), boundary = BoundaryArg::both("periodic")))]
pub(crate) fn semi_lagrangian2_vjp<'py>(
    d: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
    grad_out: &Bound<'py, PyAny>,
    dt: f64,
    spacing: (f64, f64),
    boundary: BoundaryArg,
) -> PyResult<Bound<'py, PyTuple>> {
    let s = Scheme::SemiLagrangian;
    match dtype_of(d, "d")? {
        Dtype::F32 => vjp_t::<f32>(d, u, grad_out, dt, spacing, &boundary, s),
        Dtype::F64 => vjp_t::<f64>(d, u, grad_out, dt, spacing, &boundary, s),
    }
}

/// `upwind2(d, u, *, dt, spacing=(1.0, 1.0), boundary="periodic",
/// allow_cfl_violation=False)`: one first-order upwind step, per axis
/// `d' = d − dt [u⁺ (d_{i+1} − d_i)/h + u⁻ (d_i − d_{i−1})/h]` with
/// `u⁺ = min(u, 0)`, `u⁻ = max(u, 0)`.
///
/// Shapes and dtypes: `d` is `(nx, ny)` (cell-centred), `u` is `(2, nx, ny)`
/// (`u[0]` along x, `u[1]` along y, cell-centred), both float32 or float64 of
/// one dtype; the result has `d`'s shape and dtype. `spacing` is `(dx, dy)`,
/// `boundary` `"periodic"`, `"dirichlet"`, `"closed"` or a pair per axis.
///
/// Raises `ShapeError` (`u` not `(2, nx, ny)`), `TypeError` (not float
/// arrays, or of two dtypes), `InvalidArgumentError` (`dt` or the spacing
/// not positive, an unknown boundary), `NonFiniteError`, `UnstableError` (a CFL number
/// `|u| dt / h` above 1, unless `allow_cfl_violation`).
#[pyfunction]
#[pyo3(signature = (
    d, u, *, dt, spacing = (1.0, 1.0), boundary = BoundaryArg::both("periodic"),
    allow_cfl_violation = false
))]
pub(crate) fn upwind2<'py>(
    d: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
    dt: f64,
    spacing: (f64, f64),
    boundary: BoundaryArg,
    allow_cfl_violation: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let s = Scheme::Upwind {
        allow_cfl_violation,
    };
    match dtype_of(d, "d")? {
        Dtype::F32 => forward_t::<f32>(d, u, dt, spacing, &boundary, s),
        Dtype::F64 => forward_t::<f64>(d, u, dt, spacing, &boundary, s),
    }
}

/// `upwind2_vjp(d, u, grad_out, *, dt, spacing, boundary,
/// allow_cfl_violation)`: `(∂L/∂d, ∂L/∂u)` of `upwind2` (the transposed
/// stencil for `d`, the upwind differences of `d` for `u`).
///
/// Shapes and dtypes: as `upwind2` (float32 or float64), `grad_out` of `d`'s
/// shape; returns arrays of `d`'s and `u`'s shapes. Raises as `upwind2`
/// (`ShapeError` also for `grad_out`).
#[pyfunction]
#[pyo3(signature = (
    d, u, grad_out, *, dt, spacing = (1.0, 1.0), boundary = BoundaryArg::both("periodic"),
    allow_cfl_violation = false
))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn upwind2_vjp<'py>(
    d: &Bound<'py, PyAny>,
    u: &Bound<'py, PyAny>,
    grad_out: &Bound<'py, PyAny>,
    dt: f64,
    spacing: (f64, f64),
    boundary: BoundaryArg,
    allow_cfl_violation: bool,
) -> PyResult<Bound<'py, PyTuple>> {
    let s = Scheme::Upwind {
        allow_cfl_violation,
    };
    match dtype_of(d, "d")? {
        Dtype::F32 => vjp_t::<f32>(d, u, grad_out, dt, spacing, &boundary, s),
        Dtype::F64 => vjp_t::<f64>(d, u, grad_out, dt, spacing, &boundary, s),
    }
}
