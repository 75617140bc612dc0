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

import numpy as np
import torch

import diffphys as _dp

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


def poisson_solve(b, **kwargs):
    """``p = A^{-1} b``, ``A = -∇²`` (5-point), by MG-PCG or CG in Rust
    (keyword arguments as ``diffphys.poisson_solve``). Backward (implicit):
    ``grad_b = A^{-1} grad_p``, one more solve."""
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


def project(ux, uy, *, shape, **kwargs):
    """``(ux', uy', p)``: pressure projection on a MAC grid of ``shape`` cells
    (keyword arguments as ``diffphys.Projection``). Backward:
    ``∂L/∂u = W g_u - G S(-D g_u - g_p)``, one adjoint solve."""
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


def semi_lagrangian2(d, u, *, dt, **kwargs):
    """One semi-Lagrangian step of ``d`` (``[nx, ny]``) by ``u``
    (``[2, nx, ny]``): ``d'(x) = d(x - u(x) dt)``, bilinear; backward
    through the interpolation weights."""
    return _SemiLagrangian2.apply(d, u, dict(kwargs, dt=dt))


def upwind2(d, u, *, dt, **kwargs):
    """One first-order upwind step of ``d`` by ``u`` (``[2, nx, ny]``);
    backward: the transposed stencil and the upwind differences."""
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


def flow_step(scene, ux, uy, *, steps=1, pressure=None, viscosity=None):
    """``(ux', uy', P', force)`` after ``steps`` steps of the flow ``scene``
    (a ``diffphys.FlowStep``); differentiable in ``ux``, ``uy``, the
    pressure and the viscosity (a tensor; the scene's if None). Backward:
    the steps recorded on diffphys' tape, one reverse sweep."""
    if pressure is None:
        pressure = torch.zeros(scene.shape, dtype=ux.dtype, device=ux.device)
    if viscosity is None:
        viscosity = scene.viscosity
    if not torch.is_tensor(viscosity):
        viscosity = torch.tensor(viscosity, dtype=ux.dtype, device=ux.device)
    return _Flow.apply(ux, uy, pressure, viscosity, scene, steps)
