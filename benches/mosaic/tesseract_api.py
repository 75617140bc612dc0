"""diffphys' flow step as a Mosaic navier-stokes-grid Tesseract (in-process:
``Tesseract.from_tesseract_api("benches/mosaic/tesseract_api.py")``).

Inputs and outputs are Mosaic's canonical schemas: ``v0`` is a collocated
velocity ``(N, N, 1, 2)``, ``result`` the same after ``steps`` steps, ``drag``
the x-force on the obstacle. diffphys keeps the velocity on the faces of a MAC
grid, so ``apply`` averages the cell velocities onto the faces
(``u_f[a] = (u[a-1] + u[a]) / 2``, periodic) and the final face velocities
back onto the cells (``u[i] = (u_f[i] + u_f[i+1]) / 2``); the VJP applies the
transposes of both averages around diffphys' own VJP of the steps
(``diffphys.FlowStep.vjp``: the steps recorded on the tape, every step kept,
hand-written adjoints, one pressure solve per step in the adjoint). The
pressure is solved by FFT on the periodic box without obstacle, by a sparse
Cholesky factor (MG-PCG above 128²) with one; the viscosity is explicit where
that is stable at the requested dt and implicit beyond.

Supported: the periodic box, with an optional cylinder obstacle (no-slip,
a staircase mask of the cells whose centre lies inside). Not expressed here:
Mosaic's non-periodic faces (inflow/outflow channels) and the inflow-profile
input (diffphys has both, but the collocated ``(N, N)`` layout of Mosaic's
channel needs a face convention this adapter does not yet define); a request
with them raises.

Differentiable: ``v0`` and ``viscosity`` in, ``result`` and ``drag`` out.
The solver runs in float64 and returns float32, as the schema asks; set the
environment variable ``DIFFPHYS_TESSERACT_DTYPE=float32`` (before the
Tesseract is loaded) to run it in float32, as Mosaic's JAX-CFD entrant does
(JAX's default precision). Measured at N = 128 (100 steps, 2026-11-26):
float32 is no faster (VJP 0.32 s against 0.30 s), and at N = 64 its fd_check
median relative error is 8.6e-4 against 2.2e-4 (threshold 1e-3).
"""

from __future__ import annotations

import functools
from typing import Any

import sys
from pathlib import Path as _Path

import mosaic
import numpy as np

# Mosaic's Tesseracts import its shared schemas as the top-level package
# mosaic_shared (their images copy it beside them); in-process it sits inside
# the installed mosaic package.
sys.path.insert(0, str(_Path(mosaic.__file__).parent))

from mosaic_shared.problems.navier_stokes_grid import InputSchema as _Base
from mosaic_shared.problems.navier_stokes_grid import OutputSchema as _BaseOut
from mosaic_shared.schema_types import make_differentiable
from pydantic import model_validator

import os

import diffphys as dp

# The precision of the steps (see the module docs).
DTYPE = np.dtype(os.environ.get("DIFFPHYS_TESSERACT_DTYPE", "float64"))
if DTYPE not in (np.float32, np.float64):
    raise ValueError(f"DIFFPHYS_TESSERACT_DTYPE must be float32 or float64, not {DTYPE}")


class InputSchema(make_differentiable(_Base, ["v0", "viscosity"])):
    """The canonical inputs; periodic boxes only (see the module docs)."""

    @model_validator(mode="after")
    def _check_periodic(self) -> "InputSchema":
        if not self.boundary_conditions.is_fully_periodic:
            raise ValueError("diffphys' adapter supports periodic boxes only")
        if self.inflow_profile is not None:
            raise ValueError("diffphys' adapter has no inflow profile (periodic boxes only)")
        return self


class OutputSchema(make_differentiable(_BaseOut, ["result", "drag"])):
    """The canonical outputs."""


def _obstacle_mask(obstacle: dict | None, n: int) -> np.ndarray | None:
    if obstacle is None or not obstacle.get("shape"):
        return None
    if obstacle["shape"] not in ("cylinder", "CYLINDER"):
        raise ValueError(f"diffphys' adapter: unsupported obstacle {obstacle['shape']!r}")
    c = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(c, c, indexing="ij")
    cx, cy = obstacle["center"][:2]
    return (X - cx) ** 2 + (Y - cy) ** 2 < obstacle["radius"] ** 2


@functools.lru_cache(maxsize=8)
def _scene(n: int, extent: float, dt: float, nu: float, obstacle_key: bytes | None):
    solid = None if obstacle_key is None else np.frombuffer(obstacle_key, bool).reshape(n, n)
    # the Fourier solve for the periodic box without obstacle (direct,
    # O(n log n)); with an obstacle, the sparse Cholesky up to 128², MG-PCG above
    if solid is None:
        solver = "fourier"
    else:
        solver = "cholesky" if n <= 128 else "multigrid"
    # explicit viscosity while it is stable at this dt (diffusion number
    # nu dt (1/h^2 + 1/h^2) <= 1/2), the implicit Helmholtz solve beyond (at
    # N = 256 with Mosaic's nu = 0.05, dt = 0.01 the number is 1.66: explicit
    # diffusion would need 4 substeps, and diverges without them)
    h = extent / n
    viscosity_mode = "explicit" if nu * dt * 2.0 / (h * h) <= 0.5 else "implicit"
    return dp.FlowStep((n, n), (extent, extent), sides="periodic", obstacle=solid,
                       viscosity=nu, dt=dt, pressure_solver=solver, substepping=True,
                       viscosity_mode=viscosity_mode)


def _setup(inputs: dict):
    v0 = np.asarray(inputs["v0"], DTYPE)
    n = v0.shape[0]
    if v0.shape != (n, n, 1, 2):
        raise ValueError(f"v0 must be (N, N, 1, 2), got {v0.shape}")
    solid = _obstacle_mask(inputs.get("obstacle"), n)
    nu = float(np.asarray(inputs["viscosity"]).reshape(-1)[0])
    dt = float(np.asarray(inputs["dt"]).reshape(-1)[0])
    key = None if solid is None else solid.tobytes()
    return _scene(n, float(inputs["domain_extent"]), dt, nu, key), v0[:, :, 0, :], nu


# Collocated <-> faces (periodic) and the transposes.
def _to_faces(u):
    return 0.5 * (np.roll(u[..., 0], 1, axis=0) + u[..., 0]), 0.5 * (
        np.roll(u[..., 1], 1, axis=1) + u[..., 1]
    )


def _to_faces_t(gx, gy):
    return np.stack([0.5 * (np.roll(gx, -1, axis=0) + gx), 0.5 * (np.roll(gy, -1, axis=1) + gy)],
                    axis=-1)


def _to_cells(ux, uy):
    return np.stack([0.5 * (ux + np.roll(ux, -1, axis=0)), 0.5 * (uy + np.roll(uy, -1, axis=1))],
                    axis=-1)


def _to_cells_t(g):
    return 0.5 * (g[..., 0] + np.roll(g[..., 0], 1, axis=0)), 0.5 * (
        g[..., 1] + np.roll(g[..., 1], 1, axis=1)
    )


def _zero_solid(scene, ux, uy):
    solid = scene.solid
    if solid.any():
        # Faces touching a solid cell carry no flow (no-slip obstacle).
        ux = np.where(solid | np.roll(solid, 1, axis=0), 0.0, ux)
        uy = np.where(solid | np.roll(solid, 1, axis=1), 0.0, uy)
    return ux, uy


def apply(inputs: InputSchema) -> dict:
    """Run ``steps`` diffphys flow steps from ``v0``."""
    raw = inputs.model_dump()
    scene, v0, nu = _setup(raw)
    ux, uy = _zero_solid(scene, *_to_faces(v0))
    vx, vy, _, force = scene.forward(ux, uy, steps=int(raw["steps"]), viscosity=nu)
    result = _to_cells(vx, vy)[:, :, None, :].astype(np.float32)
    return {"result": result, "drag": np.array([force[0]], np.float32)}


def vector_jacobian_product(
    inputs: InputSchema,
    vjp_inputs: set[str],
    vjp_outputs: set[str],
    cotangent_vector: dict[str, Any],
) -> dict:
    """``(∂L/∂v0, ∂L/∂viscosity)`` from the cotangents of ``result`` and ``drag``."""
    raw = inputs.model_dump()
    scene, v0, nu = _setup(raw)
    ux, uy = _zero_solid(scene, *_to_faces(v0))
    g_result = cotangent_vector.get("result") if "result" in vjp_outputs else None
    g_drag = cotangent_vector.get("drag") if "drag" in vjp_outputs else None
    gx = gy = gf = None
    if g_result is not None:
        gx, gy = _to_cells_t(np.asarray(g_result, DTYPE)[:, :, 0, :])
    if g_drag is not None:
        gf = np.array([float(np.asarray(g_drag).reshape(-1)[0]), 0.0], DTYPE)
    # every step kept on the tape, as JAX's scan keeps its residuals (100
    # steps at 256² in f64: about 1 GB); no recomputation in the reverse sweep
    g = scene.vjp(ux, uy, gx, gy, None, gf, steps=int(raw["steps"]), viscosity=nu,
                  checkpoint_every=1)
    out = {}
    if "v0" in vjp_inputs:
        gux, guy = _zero_solid(scene, g[0], g[1])
        out["v0"] = _to_faces_t(gux, guy)[:, :, None, :].astype(np.float32)
    if "viscosity" in vjp_inputs:
        out["viscosity"] = np.array([g[3]], np.float32)
    return out


def abstract_eval(abstract_inputs: InputSchema) -> dict:
    """``result`` has the shape of ``v0``; ``drag`` is ``(1,)``."""
    v0 = abstract_inputs.model_dump()["v0"]
    shape = tuple(v0["shape"]) if isinstance(v0, dict) else np.shape(v0)
    return {
        "result": {"shape": shape, "dtype": "float32"},
        "drag": {"shape": (1,), "dtype": "float32"},
    }
