//! Pressure projection on a staggered (MAC) grid with an optional obstacle,
//! and its vector–Jacobian product (one adjoint solve).

use diffphys_ops::cg::CgParams;
use diffphys_ops::mac::MacGrid;
use diffphys_ops::multigrid::Multigrid;
use diffphys_ops::projection::PressureProjection;
use diffphys_ops::CellMask;
use diffphys_tape::Real;
use numpy::{Element, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::arrays::{dtype_of, grid2, to_numpy, view, BoundaryArg, Dtype};
use crate::errors::{check, ShapeError};
use crate::solver::{info_dict, Kind, Options};

/// The projection of a velocity on the faces of a MAC grid onto its
/// divergence-free part (see `diffphys_ops::projection`):
///
/// ```text
/// b  = −D u,   p = S b  (S = A⁻¹ on the range of A = −D G, CG),   u' = W u − G p
/// ```
///
/// with the face gradient `G`, divergence `D = −Gᵀ` and the face weights `W`
/// (0 on closed faces: the walls and every face touching an obstacle cell).
///
/// Adjoint, with `g_u = ∂L/∂u'` and `g_p = ∂L/∂p`: `∂L/∂u = W g_u − G s`,
/// `s = S(−D g_u − g_p)`: one solve with the same operator.
///
/// Constructor: `Projection(shape, *, spacing=(1.0, 1.0), boundary="closed",
/// obstacle=None, preconditioner="multigrid", rel_tol=None, abs_tol=0.0,
/// max_iters=None, sweeps=2, adjoint_rel_tol=None, iterations=None)`; `obstacle` is a
/// boolean array of the cell shape, true inside the obstacle; `rel_tol`
/// None is 1e-10 for float64 arrays and 1e-5 for float32 ones.
///
/// Shapes and dtypes: for `shape = (nx, ny)` cells, `ux` is `shape_x`
/// (`(nx + 1, ny)`, the boundary faces included, closed between walls;
/// `(nx, ny)` periodic; the layout of `FlowStep`), `uy` likewise `shape_y` along y, `p`
/// is `(nx, ny)`; all float32 or float64 (the results have the inputs'
/// dtype).
///
/// Raises: `InvalidArgumentError` (unknown boundary or preconditioner, a bad
/// tolerance, an obstacle that closes every cell), `ShapeError` (faces not of
/// `shape_x`/`shape_y`), `TypeError` (not float arrays; an obstacle not a
/// bool array), `NonFiniteError`, `NotConvergedError`.
#[pyclass(module = "diffphys._native", frozen)]
pub struct Projection {
    /// The projection with the solver parameters of float32 arrays.
    single: PressureProjection,
    /// The same with those of float64 arrays.
    double: PressureProjection,
}

#[pymethods]
impl Projection {
    /// The constructor (its arguments are described on the class).
    #[new]
    #[pyo3(signature = (
        shape, *, spacing = (1.0, 1.0), boundary = BoundaryArg::both("closed"), obstacle = None,
        preconditioner = "multigrid", rel_tol = None, abs_tol = 0.0, max_iters = None,
        sweeps = 2, adjoint_rel_tol = None, iterations = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        shape: (usize, usize),
        spacing: (f64, f64),
        boundary: BoundaryArg,
        obstacle: Option<&Bound<'_, PyAny>>,
        preconditioner: &str,
        rel_tol: Option<f64>,
        abs_tol: f64,
        max_iters: Option<usize>,
        sweeps: usize,
        adjoint_rel_tol: Option<f64>,
        iterations: Option<usize>,
    ) -> PyResult<Self> {
        let grid = grid2([shape.0, shape.1], spacing, &boundary)?;
        let mac = match obstacle {
            None => MacGrid::new(grid),
            Some(solid) => {
                let solid = solid
                    .extract::<PyReadonlyArrayDyn<'_, bool>>()
                    .map_err(|_| PyTypeError::new_err("obstacle must be a numpy array of bool"))?;
                let active = solid.as_array().mapv(|s| !s);
                check(MacGrid::with_mask(
                    grid,
                    CellMask::from_array(active.view()),
                ))?
            }
        };
        let options = Options {
            preconditioner: Kind::parse(preconditioner)?,
            rel_tol,
            abs_tol,
            max_iters,
            sweeps,
            adjoint_rel_tol,
            iterations,
        };
        let params = options.params(|s| Multigrid::for_mac(&mac, s))?;
        let of = |(forward, adjoint): &(CgParams, CgParams)| {
            PressureProjection::new(mac.clone(), forward.clone())
                .with_adjoint_params(adjoint.clone())
        };
        Ok(Projection {
            single: of(params.of::<f32>()),
            double: of(params.of::<f64>()),
        })
    }

    /// The cell shape `(nx, ny)` (the pressure's).
    #[getter]
    fn shape(&self) -> (usize, usize) {
        let [nx, ny] = self.double.mac().cell_shape();
        (nx, ny)
    }

    /// The shape of the x-velocity (x-faces).
    #[getter]
    fn shape_x(&self) -> (usize, usize) {
        let [a, b] = self.double.mac().shape_x();
        (a, b)
    }

    /// The shape of the y-velocity (y-faces).
    #[getter]
    fn shape_y(&self) -> (usize, usize) {
        let [a, b] = self.double.mac().shape_y();
        (a, b)
    }

    /// `(u'_x, u'_y, p)`: the divergence-free part of `(ux, uy)` (shapes
    /// `shape_x`, `shape_y`; float32 or float64) and the pressure (`shape`);
    /// with `return_info`, `(u'_x, u'_y, p, info)`.
    ///
    /// Raises `ShapeError`, `TypeError`, `NonFiniteError`,
    /// `NotConvergedError`.
    #[pyo3(signature = (ux, uy, *, return_info = false))]
    fn project<'py>(
        &self,
        ux: &Bound<'py, PyAny>,
        uy: &Bound<'py, PyAny>,
        return_info: bool,
    ) -> PyResult<Bound<'py, PyTuple>> {
        match dtype_of(ux, "ux")? {
            Dtype::F32 => self.project_t::<f32>(ux, uy, return_info),
            Dtype::F64 => self.project_t::<f64>(ux, uy, return_info),
        }
    }

    /// `(∂L/∂u_x, ∂L/∂u_y)` from `grad_ux = ∂L/∂u'_x`, `grad_uy = ∂L/∂u'_y`
    /// and `grad_p = ∂L/∂p` (each may be None: zero; not all; shapes
    /// `shape_x`, `shape_y`, `shape`): `∂L/∂u = W g_u − G S(−D g_u − g_p)`.
    ///
    /// Raises `TypeError` (all None, or not float arrays), `ShapeError`,
    /// `NonFiniteError`, `NotConvergedError`.
    #[pyo3(signature = (grad_ux = None, grad_uy = None, grad_p = None))]
    fn vjp<'py>(
        &self,
        py: Python<'py>,
        grad_ux: Option<&Bound<'py, PyAny>>,
        grad_uy: Option<&Bound<'py, PyAny>>,
        grad_p: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let first = [grad_ux, grad_uy, grad_p]
            .into_iter()
            .flatten()
            .next()
            .ok_or_else(|| {
                PyTypeError::new_err(
                    "Projection.vjp needs at least one of grad_ux, grad_uy, grad_p",
                )
            })?;
        match dtype_of(first, "the gradient")? {
            Dtype::F32 => self.vjp_t::<f32>(py, grad_ux, grad_uy, grad_p),
            Dtype::F64 => self.vjp_t::<f64>(py, grad_ux, grad_uy, grad_p),
        }
    }
}

impl Projection {
    /// The projection whose solver parameters serve arrays of `T`.
    fn of<T: Real>(&self) -> &PressureProjection {
        if T::NAME == "f32" {
            &self.single
        } else {
            &self.double
        }
    }

    fn project_t<'py, T: Real + Element>(
        &self,
        ux: &Bound<'py, PyAny>,
        uy: &Bound<'py, PyAny>,
        return_info: bool,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let py = ux.py();
        let (ax, ay) = (view::<T>(ux, "ux")?, view::<T>(uy, "uy")?);
        self.check_faces(&ax, &ay, "ux", "uy")?;
        let (vx, vy) = (ax.as_array(), ay.as_array());
        let out = check(py.detach(|| self.of::<T>().project(vx, vy, None)))?;
        let mut items = vec![
            to_numpy(py, out.velocity_x),
            to_numpy(py, out.velocity_y),
            to_numpy(py, out.pressure),
        ];
        if return_info {
            items.push(info_dict(py, &out.info)?.into_any());
        }
        PyTuple::new(py, items)
    }

    fn vjp_t<'py, T: Real + Element>(
        &self,
        py: Python<'py>,
        grad_ux: Option<&Bound<'py, PyAny>>,
        grad_uy: Option<&Bound<'py, PyAny>>,
        grad_p: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let read =
            |a: Option<&Bound<'py, PyAny>>, what: &str| a.map(|a| view::<T>(a, what)).transpose();
        let (gx, gy, gp) = (
            read(grad_ux, "grad_ux")?,
            read(grad_uy, "grad_uy")?,
            read(grad_p, "grad_p")?,
        );
        let mac = self.double.mac();
        for (g, what, want) in [
            (&gx, "grad_ux", mac.shape_x()),
            (&gy, "grad_uy", mac.shape_y()),
            (&gp, "grad_p", mac.cell_shape()),
        ] {
            if let Some(g) = g {
                expect_shape(g.shape(), &want, what)?;
            }
        }
        let (vx, vy, vp) = (
            gx.as_ref().map(|a| a.as_array()),
            gy.as_ref().map(|a| a.as_array()),
            gp.as_ref().map(|a| a.as_array()),
        );
        let grad = check(py.detach(|| self.of::<T>().project_vjp(vx, vy, vp, None)))?;
        PyTuple::new(
            py,
            [to_numpy(py, grad.velocity_x), to_numpy(py, grad.velocity_y)],
        )
    }

    fn check_faces<T: Element>(
        &self,
        ux: &PyReadonlyArrayDyn<'_, T>,
        uy: &PyReadonlyArrayDyn<'_, T>,
        wx: &str,
        wy: &str,
    ) -> PyResult<()> {
        let mac = self.double.mac();
        expect_shape(ux.shape(), &mac.shape_x(), wx)?;
        expect_shape(uy.shape(), &mac.shape_y(), wy)
    }
}

/// A [`ShapeError`] unless `found == want`.
fn expect_shape(found: &[usize], want: &[usize], what: &str) -> PyResult<()> {
    if found == want {
        Ok(())
    } else {
        Err(ShapeError::new_err(format!(
            "shape mismatch in pressure_projection: {what} has shape {found:?}, the grid needs {want:?}"
        )))
    }
}
