//! # diffphys-py
//!
//! The Python bindings of diffphys (module `diffphys`, built with maturin from
//! `crates/python/pyproject.toml`): operators on numpy arrays of `float32` or
//! `float64`, each with its vector–Jacobian product, so that any autodiff
//! engine can wrap them (the package ships `diffphys.jax`, with
//! `jax.custom_vjp`, and `diffphys.torch`, with `torch.autograd.Function`).
//!
//! | Python | operator | adjoint |
//! | --- | --- | --- |
//! | `Poisson(shape, …).solve(b)` / `.vjp(g)` | `p = A⁻¹ b`, `A = −∇²`, MG-PCG or CG | `A⁻¹ g` (one solve) |
//! | `Projection(shape, obstacle=…).project(ux, uy)` / `.vjp(…)` | `u' = W u − G S(−D u)` on a MAC grid | `W g_u − G S(−D g_u − g_p)` |
//! | `semi_lagrangian2`, `upwind2` and their `_vjp` | one advection step of `d` by `u` | through the interpolation weights / the upwind differences |
//! | `FlowStep(shape, size, …).forward(ux, uy, steps=…)` / `.vjp(…)` | `steps` incompressible flow steps and the force on the obstacle | the steps recorded on a tape, one reverse sweep |
//!
//! The arrays are read in place (no copy for any layout numpy hands over; the
//! operators copy a non-C-order array once where they need contiguous data),
//! results are moved into numpy without a copy, and the GIL is released while
//! Rust works. Failures raise a subclass of `diffphys.DiffphysError` named by
//! kind (`ShapeError`, `NonFiniteError`, `NotConvergedError`, `UnstableError`,
//! `InvalidArgumentError`) with the Rust error's message.
//!
//! The crate builds as an ordinary library too (`cargo test`, clippy): the
//! `extension-module` feature, which maturin turns on, is off by default.
#![warn(missing_docs)]

mod advection;
mod arrays;
mod errors;
mod flow;
mod poisson;
mod projection;
mod solver;

use pyo3::prelude::*;

pub use errors::{
    DiffphysError, InvalidArgumentError, NonFiniteError, NotConvergedError, ShapeError,
    UnstableError,
};
pub use flow::FlowStep;
pub use poisson::Poisson;
pub use projection::Projection;

/// The extension module `diffphys._native`; the Python package `diffphys`
/// re-exports it with the wrappers written in Python.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("DiffphysError", py.get_type::<DiffphysError>())?;
    m.add("ShapeError", py.get_type::<ShapeError>())?;
    m.add(
        "InvalidArgumentError",
        py.get_type::<InvalidArgumentError>(),
    )?;
    m.add("NonFiniteError", py.get_type::<NonFiniteError>())?;
    m.add("NotConvergedError", py.get_type::<NotConvergedError>())?;
    m.add("UnstableError", py.get_type::<UnstableError>())?;
    m.add_class::<Poisson>()?;
    m.add_class::<Projection>()?;
    m.add_class::<FlowStep>()?;
    m.add_function(wrap_pyfunction!(advection::semi_lagrangian2, m)?)?;
    m.add_function(wrap_pyfunction!(advection::semi_lagrangian2_vjp, m)?)?;
    m.add_function(wrap_pyfunction!(advection::upwind2, m)?)?;
    m.add_function(wrap_pyfunction!(advection::upwind2_vjp, m)?)?;
    Ok(())
}
