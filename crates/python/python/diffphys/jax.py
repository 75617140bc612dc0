"""diffphys operators as JAX functions: ``jax.grad``, ``jax.vjp`` and
``jax.jit`` work through them on CPU.

Each operator is a ``jax.custom_vjp`` whose forward and backward call the Rust
forward and VJP through ``jax.pure_callback`` (the arrays cross as numpy
arrays without a copy; the GIL is released while Rust works). Under
``jax.vmap`` the callbacks run once per batch element (``vmap_method=
"sequential"``). float32 by default; float64 with ``jax_enable_x64``.

>>> import jax, jax.numpy as jnp, diffphys.jax as dj
>>> b = jnp.ones((32, 32))
>>> g = jax.grad(lambda b: jnp.sum(dj.poisson_solve(b) ** 2))(b)
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

import diffphys as _dp

try:
    import jax
    import jax.numpy as jnp
except ImportError as e:  # the engine is an extra: say which and how
    raise _dp._missing_engine("jax", e) from e

__all__ = ["flow_step", "poisson_solve", "project", "semi_lagrangian2", "upwind2"]


def _like(x):
    return jax.ShapeDtypeStruct(jnp.shape(x), jnp.result_type(x))


def _call(fn, out, *args):
    return jax.pure_callback(fn, out, *args, vmap_method="sequential")


# --- Poisson ---------------------------------------------------------------


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _poisson(solver, b):
    return _call(lambda x: solver.solve(np.asarray(x)), _like(b), b)


def _poisson_fwd(solver, b):
    return _poisson(solver, b), None


def _poisson_bwd(solver, _, g):
    return (_call(lambda x: solver.vjp(np.asarray(x)), _like(g), g),)


_poisson.defvjp(_poisson_fwd, _poisson_bwd)


def poisson_solve(b: jax.Array, **kwargs: Any) -> jax.Array:
    """``p = A^{-1} b``, ``A = -∇²`` (5-point), by MG-PCG or CG in Rust.

    Keyword arguments as ``diffphys.poisson_solve`` (``spacing``,
    ``boundary``, ``preconditioner``, ``rel_tol``, ...). Gradient (implicit):
    ``grad_b = A^{-1} grad_p``, one more solve, nothing of the forward
    iterations kept.

    ``b``: ``(nx, ny)``, float32 or float64 (``p`` alike). Raises (when the
    callback runs) ``diffphys.InvalidArgumentError``,
    ``diffphys.NonFiniteError``, ``diffphys.NotConvergedError``.
    """
    return _poisson(_dp.poisson(jnp.shape(b), **kwargs), b)


# --- projection --------------------------------------------------------------


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _project(proj, ux, uy):
    out = (_like(ux), _like(uy), jax.ShapeDtypeStruct(proj.shape, jnp.result_type(ux)))
    return _call(lambda a, b: tuple(proj.project(np.asarray(a), np.asarray(b))), out, ux, uy)


def _project_fwd(proj, ux, uy):
    return _project(proj, ux, uy), None


def _project_bwd(proj, _, grads):
    gx, gy, gp = grads
    out = (_like(gx), _like(gy))
    fn = lambda a, b, c: tuple(proj.vjp(np.asarray(a), np.asarray(b), np.asarray(c)))
    return _call(fn, out, gx, gy, gp)


_project.defvjp(_project_fwd, _project_bwd)


def project(
    ux: jax.Array, uy: jax.Array, *, shape: tuple[int, int], **kwargs: Any
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(ux', uy', p)``: the divergence-free part of the face velocity on a
    MAC grid of ``shape`` cells and its pressure (keyword arguments as
    ``diffphys.Projection``: ``obstacle``, ``boundary``, ``spacing``,
    solver options). Gradient: ``∂L/∂u = W g_u - G S(-D g_u - g_p)``.

    ``ux``, ``uy``: ``Projection.shape_x``, ``shape_y``; ``p``: ``shape``;
    float32 or float64.
    Raises ``diffphys.ShapeError``, ``diffphys.InvalidArgumentError``,
    ``diffphys.NonFiniteError``, ``diffphys.NotConvergedError``.
    """
    return _project(_dp.projection(shape, **kwargs), ux, uy)


# --- advection ---------------------------------------------------------------


def _advection(forward, vjp):
    @functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
    def op(options, d, u):
        kw = dict(options)
        return _call(lambda a, b: forward(np.asarray(a), np.asarray(b), **kw), _like(d), d, u)

    def fwd(options, d, u):
        return op(options, d, u), (d, u)

    def bwd(options, res, g):
        d, u = res
        kw = dict(options)
        fn = lambda a, b, c: tuple(vjp(np.asarray(a), np.asarray(b), np.asarray(c), **kw))
        return _call(fn, (_like(d), _like(u)), d, u, g)

    op.defvjp(fwd, bwd)
    return op


_semi_lagrangian2 = _advection(_dp.semi_lagrangian2, _dp.semi_lagrangian2_vjp)
_upwind2 = _advection(_dp.upwind2, _dp.upwind2_vjp)


def _options(kwargs):
    return tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in kwargs.items()))


def semi_lagrangian2(d: jax.Array, u: jax.Array, *, dt: float, **kwargs: Any) -> jax.Array:
    """One semi-Lagrangian step ``d'(x) = d(x - u(x) dt)`` (bilinear) of ``d``
    (``[nx, ny]``) by ``u`` (``[2, nx, ny]``); ``spacing``, ``boundary``
    (default periodic). Gradient through the interpolation weights (``∂L/∂d``
    scatters back, ``∂L/∂u`` is the bilinear slope times ``-dt/h``).
    float32 or float64. Raises ``diffphys.ShapeError``,
    ``diffphys.InvalidArgumentError``, ``diffphys.NonFiniteError``.
    """
    return _semi_lagrangian2(_options(dict(kwargs, dt=dt)), d, u)


def upwind2(d: jax.Array, u: jax.Array, *, dt: float, **kwargs: Any) -> jax.Array:
    """One first-order upwind step of ``d`` by ``u`` (``[2, nx, ny]``):
    ``d' = d - dt [u⁺ δ⁺d + u⁻ δ⁻d]`` per axis; ``spacing``, ``boundary``,
    ``allow_cfl_violation``. Gradient: the transposed stencil for ``d``, the
    upwind differences for ``u``. ``d``: ``[nx, ny]``, float32 or float64.
    Raises ``diffphys.ShapeError``, ``diffphys.InvalidArgumentError``,
    ``diffphys.NonFiniteError``, ``diffphys.UnstableError`` (CFL above 1).
    """
    return _upwind2(_options(dict(kwargs, dt=dt)), d, u)


# --- the flow step -------------------------------------------------------------


@functools.partial(jax.custom_vjp, nondiff_argnums=(0, 1))
def _flow(scene, steps, ux, uy, pressure, viscosity):
    out = (_like(ux), _like(uy), _like(pressure), jax.ShapeDtypeStruct((2,), jnp.result_type(ux)))

    def fn(a, b, p, nu):
        return tuple(
            scene.forward(np.asarray(a), np.asarray(b), steps=steps, pressure=np.asarray(p),
                          viscosity=float(nu))
        )

    return _call(fn, out, ux, uy, pressure, viscosity)


def _flow_fwd(scene, steps, ux, uy, pressure, viscosity):
    return _flow(scene, steps, ux, uy, pressure, viscosity), (ux, uy, pressure, viscosity)


def _flow_bwd(scene, steps, res, grads):
    ux, uy, pressure, viscosity = res

    def fn(a, b, p, nu, ga, gb, gp, gf):
        g = scene.vjp(np.asarray(a), np.asarray(b), np.asarray(ga), np.asarray(gb), np.asarray(gp),
                      np.asarray(gf), steps=steps, pressure=np.asarray(p), viscosity=float(nu))
        return g[0], g[1], g[2], np.asarray(g[3], dtype=g[0].dtype)

    out = (_like(ux), _like(uy), _like(pressure), _like(viscosity))
    return _call(fn, out, ux, uy, pressure, viscosity, *grads)


_flow.defvjp(_flow_fwd, _flow_bwd)


def flow_step(
    scene: _dp.FlowStep,
    ux: jax.Array,
    uy: jax.Array,
    *,
    steps: int = 1,
    pressure: jax.Array | None = None,
    viscosity: jax.Array | float | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """``(ux', uy', P', force)`` after ``steps`` steps of the flow ``scene``
    (a ``diffphys.FlowStep``) from the face velocities ``ux``, ``uy`` and
    the pressure (zero if None), with the viscosity ``viscosity`` (the
    scene's if None; differentiable). ``force`` is ``[drag, lift]`` on the
    obstacle at the end. Gradient: the steps recorded on diffphys' tape, one
    reverse sweep (every piece's adjoint hand-written; the projection's is
    one more pressure solve).

    ``ux``: ``scene.shape_x``, ``uy``: ``scene.shape_y``, ``pressure``:
    ``scene.shape``, ``force``: ``(2,)``; float32 or float64. Raises
    ``diffphys.ShapeError``, ``diffphys.InvalidArgumentError``,
    ``diffphys.NonFiniteError``, ``diffphys.UnstableError``,
    ``diffphys.NotConvergedError``.
    """
    dtype = jnp.result_type(ux)
    if pressure is None:
        pressure = jnp.zeros(scene.shape, dtype)
    if viscosity is None:
        viscosity = scene.viscosity
    return _flow(scene, steps, ux, uy, pressure, jnp.asarray(viscosity, dtype))
