//! numpy arrays in and out: the dtype of a call, read-only views without a copy,
//! and the parsing of the grid arguments every binding shares.

use diffphys_ops::{Boundary, Grid2};
use numpy::{
    Element, IntoPyArray, PyArrayDescrMethods, PyReadonlyArrayDyn, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;

use crate::errors::{check, InvalidArgumentError, ShapeError};

/// The two floating-point types every binding takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Dtype {
    /// `numpy.float32`.
    F32,
    /// `numpy.float64`.
    F64,
}

/// The dtype of `obj`, which must be a float32 or float64 numpy array.
pub(crate) fn dtype_of(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Dtype> {
    let py = obj.py();
    let array = obj.cast::<PyUntypedArray>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{what} must be a numpy array of float32 or float64, got {}",
            type_name(obj)
        ))
    })?;
    let dtype = array.dtype();
    if dtype.is_equiv_to(&numpy::dtype::<f64>(py)) {
        Ok(Dtype::F64)
    } else if dtype.is_equiv_to(&numpy::dtype::<f32>(py)) {
        Ok(Dtype::F32)
    } else {
        Err(PyTypeError::new_err(format!(
            "{what} must be a numpy array of float32 or float64, got dtype {dtype}"
        )))
    }
}

fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map_or_else(|_| "?".to_string(), |n| n.to_string())
}

/// A read-only view of `obj` as an array of `T` (no copy: any strides are
/// read in place; the operators copy a non-C-order array once if they need
/// contiguous data).
pub(crate) fn view<'py, T: Element>(
    obj: &Bound<'py, PyAny>,
    what: &str,
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    obj.extract::<PyReadonlyArrayDyn<'py, T>>().map_err(|_| {
        let found = obj.cast::<PyUntypedArray>().map_or_else(
            |_| format!("a {}", type_name(obj)),
            |a| format!("dtype {}", a.dtype()),
        );
        PyTypeError::new_err(format!(
            "{what} must be a numpy array of {}, like the first array of the call (found {found})",
            numpy::dtype::<T>(obj.py())
        ))
    })
}

/// `array` as a numpy array (the buffer is moved, not copied).
pub(crate) fn to_numpy<'py, T: Element, D: ndarray::Dimension>(
    py: Python<'py>,
    array: ndarray::Array<T, D>,
) -> Bound<'py, PyAny> {
    array.into_pyarray(py).into_any()
}

/// An array's shape as the 2D shape `[n0, n1]`, or a [`ShapeError`].
pub(crate) fn shape2(a: &PyReadonlyArrayDyn<'_, impl Element>, what: &str) -> PyResult<[usize; 2]> {
    match a.shape() {
        [n0, n1] => Ok([*n0, *n1]),
        s => Err(ShapeError::new_err(format!(
            "{what} must be a 2D array, got shape {s:?}"
        ))),
    }
}

/// A boundary by name: `"dirichlet"` (zero Dirichlet), `"closed"` (walls:
/// zero normal flow, Neumann pressure) or `"periodic"`.
pub(crate) fn boundary(name: &str) -> PyResult<Boundary> {
    match name.to_ascii_lowercase().as_str() {
        "dirichlet" | "zero_dirichlet" => Ok(Boundary::ZeroDirichlet),
        "closed" | "neumann" | "wall" => Ok(Boundary::Closed),
        "periodic" => Ok(Boundary::Periodic),
        other => Err(InvalidArgumentError::new_err(format!(
            "unknown boundary {other:?}: use \"dirichlet\", \"closed\" or \"periodic\""
        ))),
    }
}

/// The `boundary=` argument: one name for both axes, or a pair `(x, y)`.
#[derive(Debug, Clone, FromPyObject)]
pub(crate) enum BoundaryArg {
    /// The same boundary on both axes.
    Both(String),
    /// The x axis' and the y axis' boundaries.
    PerAxis(String, String),
}

impl BoundaryArg {
    /// `name` on both axes.
    pub(crate) fn both(name: &str) -> Self {
        BoundaryArg::Both(name.to_string())
    }

    /// The boundaries of the x and the y axis.
    pub(crate) fn parse(&self) -> PyResult<(Boundary, Boundary)> {
        match self {
            BoundaryArg::Both(name) => {
                let b = boundary(name)?;
                Ok((b, b))
            }
            BoundaryArg::PerAxis(x, y) => Ok((boundary(x)?, boundary(y)?)),
        }
    }
}

/// The grid of `shape` cells with `spacing` `(dx, dy)` and the boundaries of
/// `boundary`.
pub(crate) fn grid2(
    shape: [usize; 2],
    spacing: (f64, f64),
    boundary: &BoundaryArg,
) -> PyResult<Grid2> {
    let (bx, by) = boundary.parse()?;
    let grid = check(Grid2::new(shape[0], shape[1], spacing.0, spacing.1, bx))?;
    Ok(grid.with_boundaries(bx, by))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boundaries_by_name_and_per_axis() {
        let (x, y) = BoundaryArg::PerAxis("dirichlet".into(), "periodic".into())
            .parse()
            .unwrap();
        assert_eq!((x, y), (Boundary::ZeroDirichlet, Boundary::Periodic));
        let (x, y) = BoundaryArg::both("closed").parse().unwrap();
        assert_eq!((x, y), (Boundary::Closed, Boundary::Closed));
        assert!(BoundaryArg::both("sticky").parse().is_err());
        let g = grid2([4, 3], (0.5, 0.25), &BoundaryArg::both("periodic")).unwrap();
        assert_eq!((g.nx, g.ny, g.dx, g.dy), (4, 3, 0.5, 0.25));
    }
}
