"""diffphys from Python: differentiable physics operators on numpy arrays.

Every operator comes with its vector-Jacobian product (VJP), so any autodiff
engine can wrap it; ``diffphys.jax`` (``jax.custom_vjp``) and
``diffphys.torch`` (``torch.autograd.Function``) do. Arrays are float32 or
float64, read in place (no copy), results moved into numpy; the GIL is
released while Rust works. Failures raise a subclass of ``DiffphysError``
named by kind, with the Rust error's message.

Classes (solver set up once, reused by every call):

- ``Poisson(shape, ...)``: ``solve(b)`` and ``vjp(grad_p)``.
- ``Projection(shape, obstacle=..., ...)``: ``project(ux, uy)`` and ``vjp(...)``.
- ``FlowStep(shape, size, sides=..., obstacle=..., ...)``: ``forward(ux, uy,
  steps=...)`` (velocity, pressure and the force on the obstacle after
  ``steps`` steps) and ``vjp(...)``.

Functions: ``poisson_solve``, ``poisson_solve_vjp``, ``project``,
``project_vjp`` (cached solvers keyed by their arguments),
``semi_lagrangian2``, ``upwind2`` and their ``_vjp``.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from ._native import (
    DiffphysError,
    FlowStep,
    InvalidArgumentError,
    NonFiniteError,
    NotConvergedError,
    Poisson,
    Projection,
    ShapeError,
    UnstableError,
    semi_lagrangian2,
    semi_lagrangian2_vjp,
    upwind2,
    upwind2_vjp,
)

__all__ = [
    "DiffphysError",
    "InvalidArgumentError",
    "NonFiniteError",
    "NotConvergedError",
    "ShapeError",
    "UnstableError",
    "FlowStep",
    "Poisson",
    "Projection",
    "poisson",
    "projection",
    "poisson_solve",
    "poisson_solve_vjp",
    "project",
    "project_vjp",
    "semi_lagrangian2",
    "semi_lagrangian2_vjp",
    "upwind2",
    "upwind2_vjp",
]


def _missing_engine(name: str, error: ImportError) -> ImportError:
    """The ImportError of ``diffphys.jax`` or ``diffphys.torch`` when its
    engine ``name`` cannot be imported: which one, and how to install it."""
    return ImportError(
        f"diffphys.{name} needs {name}, which is not installed (import {name} failed: {error}). "
        f'Install it with diffphys: pip install "diffphys[{name}]", or from a clone of '
        f'the repository: pip install "./crates/python[{name}]".',
        name=name,
    )


def _hashable(value: Any) -> Any:
    """A cache key for a keyword argument (arrays by shape and bytes)."""
    if isinstance(value, np.ndarray):
        return ("array", value.shape, str(value.dtype), value.tobytes())
    if isinstance(value, list):
        return tuple(_hashable(v) for v in value)
    return value


@functools.lru_cache(maxsize=32)
def _cached(cls: Any, shape: tuple[int, ...], items: tuple[tuple[str, Any], ...]) -> Any:
    return cls(shape, **dict(items))


def _solver(cls: Any, shape: Sequence[int], kwargs: dict[str, Any]) -> Any:
    """The solver ``cls(shape, **kwargs)``, built once per distinct arguments."""
    arrays = {k: v for k, v in kwargs.items() if isinstance(v, np.ndarray)}
    if arrays:
        # Arrays (the obstacle) are not hashable: key by their bytes, keep the
        # array itself in a side table.
        key = tuple(sorted((k, _hashable(v)) for k, v in kwargs.items()))
        cache: dict[Any, Any] = _solver.__dict__.setdefault("arrays", {})
        if key not in cache:
            if len(cache) >= 32:
                cache.pop(next(iter(cache)))
            cache[key] = cls(tuple(shape), **kwargs)
        return cache[key]
    return _cached(cls, tuple(shape), tuple(sorted(kwargs.items())))


def poisson(shape: Sequence[int], **kwargs: Any) -> Poisson:
    """The (cached) ``Poisson`` solver of ``shape`` (cells ``(nx, ny)``) with
    the keyword arguments of ``Poisson``; one solver per distinct arguments
    (the last 32 kept).

    Raises ``InvalidArgumentError`` as ``Poisson`` does."""
    return cast(Poisson, _solver(Poisson, shape, kwargs))


def projection(shape: Sequence[int], **kwargs: Any) -> Projection:
    """The (cached) ``Projection`` of ``shape`` (cells ``(nx, ny)``) with the
    keyword arguments of ``Projection`` (an ``obstacle`` array is keyed by
    its bytes).

    Raises ``InvalidArgumentError`` as ``Projection`` does."""
    return cast(Projection, _solver(Projection, shape, kwargs))


def poisson_solve(b: NDArray[Any], **kwargs: Any) -> NDArray[Any]:
    """``p = A^{-1} b`` with ``A = -∇²`` (5-point, the grid's boundaries) by
    multigrid-preconditioned CG (``preconditioner="multigrid"``, or
    ``"jacobi"``, ``"none"``).

    Keyword arguments: ``spacing=(dx, dy)``, ``boundary`` (``"dirichlet"``,
    ``"closed"``, ``"periodic"`` or a pair per axis), ``rel_tol=1e-10``,
    ``abs_tol=0``, ``max_iters``, ``sweeps=2`` (multigrid smoothing),
    ``adjoint_rel_tol``, ``iterations`` (exactly that many CG iterations in
    each solve, without a tolerance: no convergence error, and none of the
    tolerances or ``max_iters`` with it). Without a Dirichlet axis ``A`` is
    singular: the zero-mean solution of ``A p = Π b`` is returned.

    Adjoint: ``grad_b = A^{-T} grad_p = A^{-1} grad_p`` (``poisson_solve_vjp``),
    one solve with the same operator.

    ``b``: ``(nx, ny)``, float32 or float64; ``p`` of the same shape and
    dtype. Raises ``InvalidArgumentError`` (bad options), ``TypeError`` (not
    a float array), ``NonFiniteError``, ``NotConvergedError``.
    """
    return poisson(np.shape(b), **kwargs).solve(b)


def poisson_solve_vjp(grad_p: NDArray[Any], **kwargs: Any) -> NDArray[Any]:
    """The VJP of ``poisson_solve``: ``grad_b = A^{-1} grad_p`` (same keyword
    arguments; ``grad_p`` ``(nx, ny)``, float32 or float64, ``grad_b`` of the
    same shape and dtype). Raises as ``poisson_solve``."""
    return poisson(np.shape(grad_p), **kwargs).vjp(grad_p)


def project(
    ux: NDArray[Any], uy: NDArray[Any], *, shape: Sequence[int], **kwargs: Any
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """Pressure projection on a MAC grid of ``shape`` cells: ``(ux', uy', p)``
    with ``p = S(-D u)`` (``S`` the CG solve of ``-D G``), ``u' = W u - G p``.

    ``ux`` lives on the x-faces, ``uy`` on the y-faces (``Projection.shape_x``,
    ``shape_y``); ``obstacle`` (bool, cell shape) closes the faces of solid
    cells; ``boundary="closed"`` by default. Adjoint (``project_vjp``):
    ``∂L/∂u = W g_u - G s``, ``s = S(-D g_u - g_p)``.

    float32 or float64 arrays; ``p`` is ``shape``. Raises ``ShapeError``
    (faces not of ``shape_x``/``shape_y``), ``InvalidArgumentError``,
    ``TypeError``, ``NonFiniteError``, ``NotConvergedError``.
    """
    return projection(shape, **kwargs).project(ux, uy)


def project_vjp(
    grad_ux: NDArray[Any] | None,
    grad_uy: NDArray[Any] | None,
    grad_p: NDArray[Any] | None,
    *,
    shape: Sequence[int],
    **kwargs: Any,
) -> tuple[NDArray[Any], NDArray[Any]]:
    """The VJP of ``project``: ``(∂L/∂ux, ∂L/∂uy)`` (``None`` seeds are
    zero, not all; float32 or float64, of the shapes of ``project``'s
    outputs). Raises as ``project``."""
    return projection(shape, **kwargs).vjp(grad_ux, grad_uy, grad_p)
