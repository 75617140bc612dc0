"""diffphys operators as PyTorch autograd functions (CPU tensors; tensors
on another device are moved to the CPU for the call and the results back).

Each is a ``torch.autograd.Function`` whose forward and backward call the
Rust forward and VJP on numpy views of the tensors (no copy for contiguous
CPU tensors). float32 or float64.

>>> import torch, diffphys.torch as dt
>>> b = torch.ones(32, 32, dtype=torch.float64, requires_grad=True)
>>> dt.poisson_solve(b).pow(2).sum().backward()
"""

from __future__ import annotations

from typing import Any

import numpy as np

import diffphys as _dp

try:
    import torch
except ImportError as e:  # the engine is an extra: say which and how
    raise _dp._missing_engine("torch", e) from e

__all__ = ["flow_step", "poisson_solve", "project", "semi_lagrangian2", "upwind2"]


def _np(t):
    return t.detach().to("cpu").contiguous().numpy()


def _t(a, like):
    return torch.from_numpy(np.asarray(a)).to(like.device)


class _Poisson(torch.autograd.Function):
    @staticmethod
    def forward(ctx, b, solver):
        ctx.solver = solver
        return _t(solver.solve(_np(b)), b)

    @staticmethod
    def backward(ctx, g):
        return _t(ctx.solver.vjp(_np(g)), g), None


def poisson_solve(b: torch.Tensor, **kwargs: Any) -> torch.Tensor:
    """``p = A^{-1} b``, ``A = -∇²`` (5-point), by MG-PCG or CG in Rust
    (keyword arguments as ``diffphys.poisson_solve``). Backward (implicit):
    ``grad_b = A^{-1} grad_p``, one more solve.

    ``b``: ``(nx, ny)``, float32 or float64 (``p`` alike). Raises
    ``diffphys.InvalidArgumentError``, ``TypeError`` (another dtype),
    ``diffphys.NonFiniteError``, ``diffphys.NotConvergedError``."""
    return _Poisson.apply(b, _dp.poisson(tuple(b.shape), **kwargs))


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, ux, uy, proj):
        ctx.proj = proj
        vx, vy, p = proj.project(_np(ux), _np(uy))
        return _t(vx, ux), _t(vy, ux), _t(p, ux)

    @staticmethod
    def backward(ctx, gx, gy, gp):
        ax, ay = ctx.proj.vjp(_np(gx), _np(gy), _np(gp))
        return _t(ax, gx), _t(ay, gx), None


def project(
    ux: torch.Tensor, uy: torch.Tensor, *, shape: tuple[int, int], **kwargs: Any
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(ux', uy', p)``: pressure projection on a MAC grid of ``shape`` cells
    (keyword arguments as ``diffphys.Projection``). Backward:
    ``∂L/∂u = W g_u - G S(-D g_u - g_p)``, one adjoint solve.

    ``ux``, ``uy``: the face shapes ``Projection.shape_x``, ``shape_y``;
    float32 or float64. Raises ``diffphys.ShapeError``,
    ``diffphys.InvalidArgumentError``, ``TypeError``,
    ``diffphys.NonFiniteError``, ``diffphys.NotConvergedError``."""
    return _Project.apply(ux, uy, _dp.projection(tuple(shape), **kwargs))


def _advection(forward, vjp):
    class Op(torch.autograd.Function):
        @staticmethod
        def forward(ctx, d, u, kwargs):
            ctx.kwargs = kwargs
            ctx.save_for_backward(d, u)
            return _t(forward(_np(d), _np(u), **kwargs), d)

        @staticmethod
        def backward(ctx, g):
            d, u = ctx.saved_tensors
            gd, gu = vjp(_np(d), _np(u), _np(g), **ctx.kwargs)
            return _t(gd, g), _t(gu, g), None

    return Op


_SemiLagrangian2 = _advection(_dp.semi_lagrangian2, _dp.semi_lagrangian2_vjp)
_Upwind2 = _advection(_dp.upwind2, _dp.upwind2_vjp)


def semi_lagrangian2(d: torch.Tensor, u: torch.Tensor, *, dt: float, **kwargs: Any) -> torch.Tensor:
    """One semi-Lagrangian step of ``d`` (``[nx, ny]``) by ``u``
    (``[2, nx, ny]``): ``d'(x) = d(x - u(x) dt)``, bilinear; backward
    through the interpolation weights. float32 or float64; ``spacing``,
    ``boundary`` as ``diffphys.semi_lagrangian2``.

    Raises ``diffphys.ShapeError``, ``diffphys.InvalidArgumentError``,
    ``TypeError``, ``diffphys.NonFiniteError``."""
    return _SemiLagrangian2.apply(d, u, dict(kwargs, dt=dt))


def upwind2(d: torch.Tensor, u: torch.Tensor, *, dt: float, **kwargs: Any) -> torch.Tensor:
    """One first-order upwind step of ``d`` (``[nx, ny]``) by ``u``
    (``[2, nx, ny]``): ``d' = d - dt [u⁺ δ⁺d + u⁻ δ⁻d]`` per axis; backward:
    the transposed stencil and the upwind differences. float32 or float64.

    Raises ``diffphys.ShapeError``, ``diffphys.InvalidArgumentError``,
    ``TypeError``, ``diffphys.NonFiniteError``, ``diffphys.UnstableError``
    (CFL above 1 unless ``allow_cfl_violation=True``)."""
    return _Upwind2.apply(d, u, dict(kwargs, dt=dt))


class _Flow(torch.autograd.Function):
    @staticmethod
    def forward(ctx, ux, uy, pressure, viscosity, scene, steps):
        ctx.scene, ctx.steps = scene, steps
        ctx.save_for_backward(ux, uy, pressure, viscosity)
        out = scene.forward(_np(ux), _np(uy), steps=steps, pressure=_np(pressure),
                            viscosity=float(viscosity))
        return tuple(_t(a, ux) for a in out)

    @staticmethod
    def backward(ctx, gx, gy, gp, gf):
        ux, uy, pressure, viscosity = ctx.saved_tensors
        g = ctx.scene.vjp(_np(ux), _np(uy), _np(gx), _np(gy), _np(gp), _np(gf), steps=ctx.steps,
                          pressure=_np(pressure), viscosity=float(viscosity))
        gnu = torch.tensor(g[3], dtype=viscosity.dtype, device=viscosity.device)
        return _t(g[0], gx), _t(g[1], gx), _t(g[2], gx), gnu, None, None


def flow_step(
    scene: _dp.FlowStep,
    ux: torch.Tensor,
    uy: torch.Tensor,
    *,
    steps: int = 1,
    pressure: torch.Tensor | None = None,
    viscosity: torch.Tensor | float | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(ux', uy', P', force)`` after ``steps`` steps of the flow ``scene``
    (a ``diffphys.FlowStep``); differentiable in ``ux``, ``uy``, the
    pressure and the viscosity (a tensor; the scene's if None). Backward:
    the steps recorded on diffphys' tape, one reverse sweep.

    ``ux``: ``scene.shape_x``, ``uy``: ``scene.shape_y``, ``pressure``:
    ``scene.shape`` (zero if None), ``force``: ``(2,)`` (drag, lift);
    float32 or float64, one dtype. Unbatched: loop or stack over samples.
    Raises ``diffphys.ShapeError``, ``diffphys.InvalidArgumentError``,
    ``TypeError``, ``diffphys.NonFiniteError``, ``diffphys.UnstableError``
    (a Courant number above the scene's limit), ``diffphys.NotConvergedError``."""
    if pressure is None:
        pressure = torch.zeros(scene.shape, dtype=ux.dtype, device=ux.device)
    if viscosity is None:
        viscosity = scene.viscosity
    if not torch.is_tensor(viscosity):
        viscosity = torch.tensor(viscosity, dtype=ux.dtype, device=ux.device)
    return _Flow.apply(ux, uy, pressure, viscosity, scene, steps)
