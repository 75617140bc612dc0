"""diffphys' flow step as a Mosaic navier-stokes-grid Tesseract: our entry
to Mosaic (this folder is what goes to ``mosaic/tesseracts/navier-stokes-grid/
diffphys/`` upstream, see README.md beside it), and the adapter our own runner
loads in-process (``Tesseract.from_tesseract_api`` on this file,
benches/mosaic/mosaic_run.py).

Inputs and outputs are Mosaic's canonical schemas: ``v0`` is a collocated
velocity ``(N, N, 1, 2)``, ``result`` the same after ``steps`` steps, ``drag``
the x-force as Mosaic's entrants report it (PhiFlow, XLB and PICT alike): the
mean over the last ``max(1, steps // 2)`` steps, with Mosaic's sign (the force
on the fluid, negative for flow in +x), i.e. minus the mean of
``diffphys.FlowStep``'s ``force[0]`` (the force of the flow on the obstacle,
its surface integral of pressure and shear) over those steps; 0 without an
obstacle. Its VJP runs those last steps one at a time (each seeds its own
force) and the steps before them in one ``FlowStep.vjp``. diffphys keeps the velocity on the faces of a MAC
grid, so ``apply`` moves the cell velocities onto the faces and the final
face velocities back onto the cells (the face convention below); the VJP
applies the transposes of both around diffphys' own VJP of the steps
(``diffphys.FlowStep.vjp``: the steps recorded on the tape, every step kept,
hand-written adjoints, one pressure solve per step in the adjoint). The
pressure is solved by FFT on the periodic box without obstacle, otherwise by
a sparse Cholesky factor (MG-PCG above 128²); the viscosity is explicit where
that is stable at the requested dt and implicit beyond.

Boundary conditions (Mosaic's ``GridBC`` face -> diffphys side: ``x_lo`` left,
``x_hi`` right, ``y_lo`` bottom, ``y_hi`` top):

=================================================  ===========================
Mosaic face                                        diffphys side
=================================================  ===========================
``periodic`` (both faces of the axis)              ``"periodic"``
``no_slip``                                        ``"no_slip"``
``dirichlet``, ``value`` None or ``(0, 0)``        ``"no_slip"``
``dirichlet``, value tangential only ``(vt)``      ``("moving", vt)`` (the
                                                   tangential component: vx on
                                                   y faces, vy on x faces)
``dirichlet``, value normal only ``(vn)``          ``"inflow"``, uniform profile
                                                   ``vn`` (the normal component
                                                   as a face velocity, so an
                                                   inflow through x_hi is < 0)
``neumann`` (zero normal derivative)               ``"outflow"`` (zero-gradient
                                                   velocity, ``p = 0`` one cell
                                                   outside)
``inflow_profile`` (x_lo ``no_slip``/``dirichlet``)  ``"inflow"`` on the left,
                                                   ``u_x(y)`` the profile,
                                                   ``u_y = 0``
``inflow_profile`` with x ``periodic`` (drag_opt)  ``"inflow"`` on the left
                                                   (the profile), ``"outflow"``
                                                   on the right
=================================================  ===========================

Mosaic's ``optimization/drag_opt`` gives the profile with x periodic (its
``make_inputs``: x_lo, x_hi periodic, y no_slip, a cylinder). The schema says
the profile "overrides the x_lo Dirichlet BC": x_lo becomes a Dirichlet
inflow, u = (profile, 0), which ends the periodicity of x, so its partner
x_hi becomes the open side the mass leaves by (zero-gradient velocity,
``p = 0``): an inflow/outflow channel, as Mosaic's PICT entrant builds it.
We chose it over the other reading (PhiFlow's entrant overwrites the x = 0
face column inside the still periodic box, XLB's resets the x = 0
populations) because it is what the schema's words describe (a Dirichlet
condition on the x_lo face), it is the scene diffphys already has with its
adjoint, and it keeps the flow upstream of the cylinder the prescribed
profile: in the periodic box with a forced column the wake leaving through
x_hi re-enters at x_lo around the forced column. The price: the flow the
drag is measured in differs from PhiFlow's and XLB's, so the drags differ
between entrants (Mosaic ranks the relative reduction).

The other reading can be run for comparison: with the environment variable
``DIFFPHYS_TESSERACT_INFLOW=forced-column`` (default ``channel``) x stays
periodic and the x = 0 face column is set to the profile before every step
(PhiFlow's entrant's reading; no Dirichlet side, so the projection then
moves the column as it moves every face). Its VJP runs every step on its
own (200 single-step VJPs at drag_opt's horizon): setting a face is, in
the adjoint, zeroing its gradient and adding it to the profile's.

An ``inflow_profile`` whose length is not N is resampled linearly onto the N
cells along x_lo (on ``linspace(0, 1)``, as Mosaic's JAX-CFD, PhiFlow and
INS.jl entrants do); its gradient is the transpose of that resampling.

Face convention (collocated ``(N, N)`` <-> MAC faces). The x-velocity lives
on the x-faces, the y-velocity on the y-faces; along its own axis a component
is averaged, along the other it is not moved. On a periodic axis (N faces,
face ``a`` between cells ``a-1`` and ``a``, wrapped) nothing changes from the
periodic adapter: ``u_f[a] = (u[a-1] + u[a]) / 2`` with ``u[-1] = u[N-1]``,
``u[i] = (u_f[i] + u_f[i+1]) / 2`` with ``u_f[N] = u_f[0]``; the results on
fully periodic inputs are bit-identical to the adapter before the
non-periodic faces were added. On a non-periodic axis (N + 1 faces,
``0`` and ``N`` on the two boundaries, no wrapping): interior faces
``u_f[a] = (u[a-1] + u[a]) / 2`` for ``1 <= a <= N-1``; a boundary face takes
the boundary's value: ``0`` on a wall (no-slip, moving), the profile on the
inflow face, and the adjacent cell's value on an outflow face (zero normal
gradient: ``u_f[0] = u[0]``, ``u_f[N] = u[N-1]``). Back to the cells,
``u[i] = (u_f[i] + u_f[i+1]) / 2`` for every cell, the boundary faces
included (so a cell next to a wall carries half its interior face). Faces
touching a solid cell are zero (no-slip obstacle, a staircase mask of the
cells whose centre lies inside the cylinder, on the default staircase body).
diffphys sets the wall, inflow
and obstacle faces again at the start of every step, so the VJP gives them no
gradient to ``v0``; the inflow profile gets the gradient of every step's
inflow faces.

The body. Mosaic's cylinder (centre, radius) is, by default, a staircase:
the cells whose centre lies inside the circle are solid, their faces pinned
to zero, and the drag is diffphys' surface integral over the staircase. At
Mosaic's drag_opt grid (N = 32, radius 0.05 = 1.6 cells) that is 12 cells,
4 across: a frontal width of 0.125 against the nominal diameter 0.1. Set
the environment variable ``DIFFPHYS_TESSERACT_BODY`` (before the Tesseract is
loaded) to ``immersed`` for diffphys' immersed circle of the nominal radius
(``FlowStep(immersed=...)``, a direct-forcing immersed boundary, Fadlun et
al. 2000: the free faces next to the body are set to the linear
interpolation between zero on the true circle and the next face outward;
no cell is solid, the faces inside the circle are forced to zero),
``immersed-solid`` for the same forcing with the circle's cells solid, or
``immersed-consistent`` for the projection-consistent forcing. The immersed
circle is the nominal geometry Mosaic's schema gives; the staircase is a
coarse-grid approximation of it. On an immersed circle the drag is the
x-force of the momentum balance over a square of faces about the body
(``_ControlVolume``: half-width 3 r, at least 4 cells clear of the circle;
the surface terms of each tail step's end state and the momentum change
inside the box over the tail), which is a function of the states and so
has a gradient through the steps (the forcing's own momentum exchange,
which ``FlowStep`` reports as its force, is not on diffphys' tape).

The advection. Every step advects the velocity semi-Lagrangian by default
(``FlowStep(advection="semi_lagrangian")``: a backward trace and a linear
interpolation, first order, whose interpolation diffuses). Set the
environment variable ``DIFFPHYS_TESSERACT_ADVECTION`` (before the
Tesseract is loaded) to ``maccormack`` for diffphys' MacCormack advection
(a forward and a backward semi-Lagrangian trace, second order, with its
limiter; ``FlowStep(advection="maccormack")``, with its adjoint). The
default stays semi-Lagrangian so that the figures measured with it stand;
docs/results/mosaic.md (optimization/drag_opt) measures what each gives.

Not supported (each raises a ValueError naming the face and kind): a
``dirichlet`` value with both a normal and a tangential component (diffphys'
inflow has no tangential velocity, its moving wall no normal one); a value
that is not 2 components; ``periodic`` on one face of an axis only; more than
one inflow face (a normal ``dirichlet`` value or the profile) or an inflow
without a ``neumann`` (outflow) face for the mass to leave by (x periodic
with the profile gives itself one, above); an ``inflow_profile`` with
``x_lo`` ``neumann``; non-periodic ``z``
faces (the solver is 2-D); obstacles other than the cylinder; an obstacle
that covers part of the inflow side (diffphys' scene check, re-raised as a
ValueError). diffphys' free-slip side has no Mosaic face kind (``neumann`` is
read as an open outflow, as PhiFlow's entrant reads it, not as a symmetry
plane).

Differentiable: ``v0``, ``viscosity`` and ``inflow_profile`` in, ``result``
and ``drag`` out. The Dirichlet values (wall speeds, uniform inflow) are not
array inputs of Mosaic's schema and get no gradient here, though diffphys
has one for them. The solver runs in float64 and returns float32, as the
schema asks; set the environment variable ``DIFFPHYS_TESSERACT_DTYPE=float32``
(before the Tesseract is loaded) to run it in float32, as Mosaic's JAX-CFD
entrant does (JAX's default precision). Measured at N = 128 (100 steps,
2026-11-26, periodic): float32 is no faster (VJP 0.32 s against 0.30 s), and
at N = 64 its fd_check median relative error is 8.6e-4 against 2.2e-4
(threshold 1e-3). Non-periodic (2026-11-26): Mosaic's ``forward/cylinder``
through its own runner (benches/mosaic/mosaic_run.py, N = 64, 500 steps)
gives l2_error_rel 0.099 / 0.104 / 0.145 / 0.136 at nu = 0.05 / 0.02 / 0.01 /
0.005 against Mosaic's precomputed reference; the VJP checks on walls,
outflow and the inflow profile are in benches/mosaic/channel_check.py.

Memory: each ``FlowStep`` keeps the buffers of its last VJP for the next
(``buffer_limit_bytes``; 474 MB after a 100-step VJP at N = 256), and this
adapter lets only the scene of the latest VJP keep them (``_keep_buffers_of``).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

try:
    # In the Tesseract image mosaic_shared is an installed package
    # (tesseract_requirements.txt: ../../../mosaic_shared, as every entrant).
    import mosaic_shared  # noqa: F401
except ImportError:
    # In-process (benches/mosaic/mosaic_run.py) it sits inside the installed
    # mosaic-bench package, as a top-level folder of it.
    import sys
    from pathlib import Path as _Path

    import mosaic

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

# The body of Mosaic's cylinder (see the module docs): "staircase" (the
# cells whose centre lies inside it, solid), or the immersed circle of the
# nominal radius, "immersed" (forced interior, direct forcing),
# "immersed-solid" (its cells solid) or "immersed-consistent" (forced
# interior, projection-consistent forcing).
_IMMERSED = {"immersed": ("forced", "direct"), "immersed-solid": ("solid", "direct"),
             "immersed-consistent": ("forced", "consistent")}
BODY = os.environ.get("DIFFPHYS_TESSERACT_BODY", "staircase")
# How an inflow_profile given with x periodic is read (see the module docs):
# "channel" (x_lo a Dirichlet inflow, x_hi an outflow) or "forced-column"
# (x stays periodic, the x = 0 face column is set to the profile before
# every step, as Mosaic's PhiFlow entrant does).
INFLOW = os.environ.get("DIFFPHYS_TESSERACT_INFLOW", "channel")
if INFLOW not in ("channel", "forced-column"):
    raise ValueError(f"DIFFPHYS_TESSERACT_INFLOW must be channel or forced-column, not {INFLOW!r}")
# The advection of every step (see the module docs): "semi_lagrangian" or
# "maccormack" (limited), the names FlowStep takes.
ADVECTION = os.environ.get("DIFFPHYS_TESSERACT_ADVECTION", "semi_lagrangian")
if ADVECTION not in ("semi_lagrangian", "maccormack"):
    raise ValueError("DIFFPHYS_TESSERACT_ADVECTION must be semi_lagrangian or maccormack, "
                     f"not {ADVECTION!r}")
if BODY != "staircase" and BODY not in _IMMERSED:
    raise ValueError("DIFFPHYS_TESSERACT_BODY must be staircase, "
                     f"{', '.join(_IMMERSED)}, not {BODY!r}")

# Mosaic's faces in diffphys' side order (left, right, bottom, top), with the
# axis each is normal to.
_FACES = (("x_lo", "left", 0), ("x_hi", "right", 0), ("y_lo", "bottom", 1), ("y_hi", "top", 1))


def _kind(face: dict) -> str:
    t = face["type"]
    return str(getattr(t, "value", t))


@functools.lru_cache(maxsize=64)
def _plan_cached(bc_key: tuple, has_profile: bool, inflow: str = "channel"):
    bc = {name: {"type": t, "value": None if v is None else list(v)} for name, t, v in bc_key}
    return _plan_uncached(bc, has_profile, inflow)


def _plan(bc: dict, has_profile: bool):
    """The diffphys sides of Mosaic's ``boundary_conditions`` (a dict of face
    dicts) and ``inflow_profile`` (given or not), checked (see the module
    docs): ``None`` for the fully periodic box, else a tuple of
    ``(face, side, spec, uniform)`` in the order left, right, bottom, top,
    with ``spec`` diffphys' side condition and ``uniform`` the uniform inflow
    speed of a normal Dirichlet value (None elsewhere, and for the profile)."""
    key = tuple(
        (name, _kind(bc[name]),
         None if bc[name].get("value") is None else tuple(float(x) for x in bc[name]["value"]))
        for name in ("x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi")
    )
    return _plan_cached(key, bool(has_profile), INFLOW)


def _column(bc: dict, has_profile: bool, inflow: str) -> bool:
    """Whether the profile is a forced face column in the periodic x axis."""
    return has_profile and inflow == "forced-column" and _kind(bc["x_lo"]) == "periodic"


def _plan_uncached(bc: dict, has_profile: bool, inflow: str = "channel"):
    for name in ("z_lo", "z_hi"):
        if _kind(bc[name]) != "periodic":
            raise ValueError(
                f"diffphys' adapter: {name} is {_kind(bc[name])!r}; the solver is 2-D, "
                "the z faces must stay 'periodic' (the default)")
    for lo, hi in (("x_lo", "x_hi"), ("y_lo", "y_hi")):
        if (_kind(bc[lo]) == "periodic") != (_kind(bc[hi]) == "periodic"):
            raise ValueError(
                f"diffphys' adapter: {lo} is {_kind(bc[lo])!r} and {hi} is {_kind(bc[hi])!r}; "
                "diffphys makes an axis periodic on both faces or on neither")
    column = _column(bc, has_profile, inflow)
    if (not has_profile or column) and all(_kind(bc[name]) == "periodic" for name, _, _ in _FACES):
        return None
    plan = []
    for name, side, axis in _FACES:
        kind = _kind(bc[name])
        value = bc[name].get("value")
        uniform = None
        if kind == "periodic":
            spec = "periodic"
        elif kind == "no_slip":
            spec = "no_slip"
        elif kind == "neumann":
            spec = "outflow"
        elif kind == "dirichlet":
            if value is None:
                spec = "no_slip"
            else:
                if len(value) != 2:
                    raise ValueError(
                        f"diffphys' adapter: {name} 'dirichlet' value {list(value)} has "
                        f"{len(value)} components; a 2-D velocity has 2")
                vn, vt = float(value[axis]), float(value[1 - axis])
                if vn == 0.0 and vt == 0.0:
                    spec = "no_slip"
                elif vn == 0.0:
                    spec = ("moving", vt)
                elif vt == 0.0:
                    spec, uniform = "inflow", vn
                else:
                    raise ValueError(
                        f"diffphys' adapter: {name} 'dirichlet' value {list(value)} has both a "
                        "normal and a tangential component; diffphys' inflow side has no "
                        "tangential velocity and its moving wall no normal one")
        else:
            raise ValueError(f"diffphys' adapter: {name} has the unknown kind {kind!r}")
        if name == "x_lo" and has_profile and not column:
            if kind == "neumann":
                raise ValueError(
                    "diffphys' adapter: inflow_profile with x_lo 'neumann': the profile "
                    "overrides the x_lo Dirichlet condition, so x_lo must be 'dirichlet', "
                    "'no_slip' or 'periodic' (Mosaic's drag_opt: x_lo becomes the inflow, "
                    "x_hi the outflow)")
            spec, uniform = "inflow", None
        if name == "x_hi" and has_profile and kind == "periodic" and not column:
            # the profile's Dirichlet x_lo ends the x axis's periodicity: its
            # periodic partner x_hi becomes the open side the mass leaves by
            spec = "outflow"
        plan.append((name, side, spec, uniform))
    inflows = [p[0] for p in plan if p[2] == "inflow"]
    if len(inflows) > 1:
        raise ValueError(
            f"diffphys' adapter: {len(inflows)} inflow faces ({', '.join(inflows)}: a normal "
            "'dirichlet' value or the inflow_profile); diffphys has at most one inflow side")
    if inflows and not any(p[2] == "outflow" for p in plan):
        raise ValueError(
            f"diffphys' adapter: {inflows[0]} is an inflow but no face is 'neumann'; "
            "diffphys' inflow needs an outflow side for the mass to leave by")
    return tuple(plan)


class InputSchema(make_differentiable(_Base, ["v0", "viscosity", "inflow_profile"])):
    """The canonical inputs; the faces diffphys can represent (see the module
    docs)."""

    @model_validator(mode="after")
    def _check_faces(self) -> "InputSchema":
        _plan(self.boundary_conditions.model_dump(), self.inflow_profile is not None)
        return self


class OutputSchema(make_differentiable(_BaseOut, ["result", "drag"])):
    """The canonical outputs."""


def _cylinder(obstacle: dict | None) -> tuple[float, float, float] | None:
    """Mosaic's cylinder as ``(cx, cy, r)`` (None without an obstacle)."""
    if obstacle is None or not obstacle.get("shape"):
        return None
    shape = str(getattr(obstacle["shape"], "value", obstacle["shape"]))
    if shape not in ("cylinder", "CYLINDER"):
        raise ValueError(f"diffphys' adapter: unsupported obstacle {shape!r}")
    cx, cy = obstacle["center"][:2]
    return float(cx), float(cy), float(obstacle["radius"])


def _obstacle_mask(circle: tuple[float, float, float], n: int) -> np.ndarray:
    """The staircase of ``circle``: the cells whose centre lies inside it."""
    c = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(c, c, indexing="ij")
    cx, cy, r = circle
    return (X - cx) ** 2 + (Y - cy) ** 2 < r ** 2


@functools.lru_cache(maxsize=8)
def _scene(n: int, extent: float, dt: float, nu: float, circle: tuple | None,
           plan: tuple | None = None, kind: str = "staircase",
           advection: str = "semi_lagrangian"):
    # the body (module docs, BODY): a staircase mask, or the immersed circle
    # with its interior and forcing scheme
    solid, body = None, {}
    if circle is not None and kind == "staircase":
        solid = _obstacle_mask(circle, n)
    elif circle is not None:
        interior, scheme = _IMMERSED[kind]
        body = {"immersed": circle, "immersed_interior": interior, "immersed_scheme": scheme}
    # the Fourier solve for the periodic box without obstacle (direct,
    # O(n log n)); otherwise the sparse Cholesky up to 128², MG-PCG above
    if solid is None and not body and plan is None:
        solver = "fourier"
    else:
        solver = "cholesky" if n <= 128 else "multigrid"
    # explicit viscosity while it is stable at this dt (diffusion number
    # nu dt (1/h^2 + 1/h^2) <= 1/2), the implicit Helmholtz solve beyond (at
    # N = 256 with Mosaic's nu = 0.05, dt = 0.01 the number is 1.66: explicit
    # diffusion would need 4 substeps, and diverges without them)
    h = extent / n
    viscosity_mode = "explicit" if nu * dt * 2.0 / (h * h) <= 0.5 else "implicit"
    if plan is None:
        return dp.FlowStep((n, n), (extent, extent), sides="periodic", obstacle=solid,
                           viscosity=nu, dt=dt, pressure_solver=solver, substepping=True,
                           viscosity_mode=viscosity_mode, advection=advection, **body)
    sides = {side: spec for _, side, spec, _ in plan}
    # the scene's default profile is a placeholder: every call passes its own
    inflow = [0.0] * n if any(spec == "inflow" for _, _, spec, _ in plan) else None
    try:
        return dp.FlowStep((n, n), (extent, extent), sides=sides, obstacle=solid,
                           viscosity=nu, dt=dt, inflow=inflow, pressure_solver=solver,
                           substepping=True, viscosity_mode=viscosity_mode, advection=advection,
                           **body)
    except dp.DiffphysError as e:
        faces = ", ".join(f"{name} -> {spec!r}" for name, _, spec, _ in plan)
        raise ValueError(f"diffphys' adapter: diffphys cannot build this scene ({faces}): {e}") from e


def _resample(m: int, n: int) -> np.ndarray | None:
    """The (n, m) matrix of the linear resampling of a profile of m values on
    linspace(0, 1, m) onto linspace(0, 1, n) (None when m == n)."""
    if m == n:
        return None
    src, dst = np.linspace(0.0, 1.0, m), np.linspace(0.0, 1.0, n)
    return np.stack([np.interp(dst, src, e) for e in np.eye(m)], axis=1)


class _Layout:
    """The boundary of each axis's two ends for the face conversions:
    ``lo[axis]``, ``hi[axis]`` each ``("periodic" | "wall" | "outflow" |
    "inflow", value along the face or None)``; ``q`` the inflow profile on the
    cells along the inflow side (None without one), ``resample`` its
    resampling matrix from ``inflow_profile`` (None if none or the identity)."""

    def __init__(self, plan, n: int, profile, column: bool = False):
        self.periodic = plan is None
        self.q = None
        self.column = None
        self.resample = None
        self.profile_given = profile is not None
        if column:
            # the profile as the x = 0 face column of a periodic x axis
            p = self._profile(profile)
            self.resample = _resample(p.shape[0], n)
            self.column = np.asarray(p if self.resample is None else self.resample @ p, DTYPE)
        if plan is None:
            self.lo = self.hi = (("periodic", None), ("periodic", None))
            return
        ends = {}
        for name, _, spec, uniform in plan:
            if spec == "periodic":
                ends[name] = ("periodic", None)
            elif spec == "outflow":
                ends[name] = ("outflow", None)
            elif spec == "inflow":
                if uniform is not None:
                    self.q = np.full(n, uniform, DTYPE)
                else:
                    p = self._profile(profile)
                    self.resample = _resample(p.shape[0], n)
                    q = p if self.resample is None else self.resample @ p
                    self.q = np.asarray(q, DTYPE)
                ends[name] = ("inflow", self.q)
            else:  # no-slip or moving wall: no normal velocity
                ends[name] = ("wall", None)
        self.lo = (ends["x_lo"], ends["y_lo"])
        self.hi = (ends["x_hi"], ends["y_hi"])

    @staticmethod
    def _profile(profile) -> np.ndarray:
        p = np.asarray(profile, np.float64)
        if p.ndim != 1 or p.size == 0:
            raise ValueError(
                f"diffphys' adapter: inflow_profile has shape {p.shape}; it is "
                "u_x(y), one value or more along x_lo, shape (M,)")
        return p


def _setup(inputs: dict):
    v0 = np.asarray(inputs["v0"], DTYPE)
    n = v0.shape[0]
    if v0.shape != (n, n, 1, 2):
        raise ValueError(f"v0 must be (N, N, 1, 2), got {v0.shape}")
    circle = _cylinder(inputs.get("obstacle"))
    nu = float(np.asarray(inputs["viscosity"]).reshape(-1)[0])
    dt = float(np.asarray(inputs["dt"]).reshape(-1)[0])
    key = circle
    profile = inputs.get("inflow_profile")
    plan = _plan(inputs["boundary_conditions"], profile is not None)
    extent = float(inputs["domain_extent"])
    scene = _scene(n, extent, dt, nu, key, plan, BODY, ADVECTION)
    drag = None if circle is None else _Drag(scene, circle, extent)
    column = _column(inputs["boundary_conditions"], profile is not None, INFLOW)
    return scene, v0[:, :, 0, :], nu, _Layout(plan, n, profile, column), drag


def _along(a: np.ndarray, axis: int, s) -> tuple:
    return tuple(s if k == axis else slice(None) for k in range(a.ndim))


# Collocated <-> faces along one axis (the module docs' convention), and the
# transposes. ``lo``/``hi`` are the ends of that axis (_Layout).
def _faces_axis(c, axis, lo, hi):
    if lo[0] == "periodic":
        return 0.5 * (np.roll(c, 1, axis=axis) + c)
    n = c.shape[axis]
    shape = list(c.shape)
    shape[axis] = n + 1
    f = np.zeros(shape, c.dtype)
    f[_along(f, axis, slice(1, n))] = 0.5 * (c[_along(c, axis, slice(0, n - 1))]
                                             + c[_along(c, axis, slice(1, n))])
    for face, cell, (kind, value) in ((0, 0, lo), (n, n - 1, hi)):
        if kind == "outflow":
            f[_along(f, axis, face)] = c[_along(c, axis, cell)]
        elif kind == "inflow":
            f[_along(f, axis, face)] = value
        # a wall: 0
    return f


def _faces_axis_t(g, axis, lo, hi):
    if lo[0] == "periodic":
        return 0.5 * (np.roll(g, -1, axis=axis) + g)
    n = g.shape[axis] - 1
    shape = list(g.shape)
    shape[axis] = n
    c = np.zeros(shape, g.dtype)
    inner = 0.5 * g[_along(g, axis, slice(1, n))]  # faces 1..n-1
    c[_along(c, axis, slice(0, n - 1))] += inner
    c[_along(c, axis, slice(1, n))] += inner
    # a boundary face depends on the cells only on an outflow (its adjacent
    # cell's value); walls and the inflow get no gradient from v0
    for face, cell, (kind, _) in ((0, 0, lo), (n, n - 1, hi)):
        if kind == "outflow":
            c[_along(c, axis, cell)] += g[_along(g, axis, face)]
    return c


def _cells_axis(f, axis, periodic):
    if periodic:
        return 0.5 * (f + np.roll(f, -1, axis=axis))
    n = f.shape[axis] - 1
    return 0.5 * (f[_along(f, axis, slice(0, n))] + f[_along(f, axis, slice(1, n + 1))])


def _cells_axis_t(g, axis, periodic):
    if periodic:
        return 0.5 * (g + np.roll(g, 1, axis=axis))
    n = g.shape[axis]
    shape = list(g.shape)
    shape[axis] = n + 1
    f = np.zeros(shape, g.dtype)
    f[_along(f, axis, slice(0, n))] += 0.5 * g
    f[_along(f, axis, slice(1, n + 1))] += 0.5 * g
    return f


def _to_faces(u, lay: _Layout):
    return (_faces_axis(u[..., 0], 0, lay.lo[0], lay.hi[0]),
            _faces_axis(u[..., 1], 1, lay.lo[1], lay.hi[1]))


def _to_faces_t(gx, gy, lay: _Layout):
    return np.stack([_faces_axis_t(gx, 0, lay.lo[0], lay.hi[0]),
                     _faces_axis_t(gy, 1, lay.lo[1], lay.hi[1])], axis=-1)


def _to_cells(ux, uy, lay: _Layout):
    return np.stack([_cells_axis(ux, 0, lay.lo[0][0] == "periodic"),
                     _cells_axis(uy, 1, lay.lo[1][0] == "periodic")], axis=-1)


def _to_cells_t(g, lay: _Layout):
    return (_cells_axis_t(g[..., 0], 0, lay.lo[0][0] == "periodic"),
            _cells_axis_t(g[..., 1], 1, lay.lo[1][0] == "periodic"))


def _solid_faces(solid, axis, periodic):
    """The faces along ``axis`` touching a solid cell."""
    if periodic:
        return solid | np.roll(solid, 1, axis=axis)
    pad = np.zeros_like(solid[_along(solid, axis, slice(0, 1))])
    return np.concatenate([solid, pad], axis=axis) | np.concatenate([pad, solid], axis=axis)


def _zero_solid(scene, lay: _Layout, ux, uy):
    solid = scene.solid
    if solid.any():
        # Faces touching a solid cell carry no flow (no-slip obstacle).
        ux = np.where(_solid_faces(solid, 0, lay.lo[0][0] == "periodic"), 0.0, ux)
        uy = np.where(_solid_faces(solid, 1, lay.lo[1][0] == "periodic"), 0.0, uy)
    return ux, uy


def _tail(steps: int) -> int:
    """The steps the drag is averaged over: the last ``steps // 2`` (at
    least one), as Mosaic's PhiFlow, XLB and PICT entrants average it."""
    return max(1, steps // 2)


class _ControlVolume:
    """The x-force of the flow on whatever lies inside a square of faces
    about the body, by the momentum balance over it (density 1):

    ``F_x = ∮ (−p n_x + ν ∂u_x/∂n − u_x (u·n)) dS − d/dt ∫ u_x dV``

    on the midpoint rule of diffphys' ``control_volume_force``
    (crates/flow/src/validation/control_volume.rs): on the left and right
    edges the face's own ``u_x``, the pressure averaged from the cells on
    either side, ``∂u_x/∂x`` a central difference of faces; on the bottom
    and top edges ``v`` the face's own, ``u_x`` and ``∂u_x/∂y`` from the
    cell-centred ``u_x`` on either side. It never reads the body, so it
    gives the force on the immersed circle as a function of the state
    (quadratic in the velocity, linear in the pressure), whose gradient
    ``surface`` and ``momentum`` return beside the value (by hand: the
    terms are products of two faces at most)."""

    def __init__(self, scene, circle, extent: float):
        nx, ny = scene.shape
        cx, cy, r = circle
        self.dx, self.dy = extent / nx, extent / ny
        # half-width 3 r (1.5 diameters), at least 4 cells clear of the
        # circle: the stencil reaches two cells beyond an edge, and
        # diffphys' check wants two fluid cells between an edge and the body
        half = max(3.0 * r, r + 4.0 * max(self.dx, self.dy))
        self.i0, self.i1 = (int(round((cx - half) / self.dx)), int(round((cx + half) / self.dx)))
        self.j0, self.j1 = (int(round((cy - half) / self.dy)), int(round((cy + half) / self.dy)))
        if not (1 <= self.i0 < self.i1 <= nx - 2 and 1 <= self.j0 < self.j1 <= ny - 2):
            raise ValueError(
                f"diffphys' adapter: the control volume about the cylinder {circle} (faces "
                f"x {self.i0}..{self.i1}, y {self.j0}..{self.j1}) leaves the {nx} x {ny} grid")

    def surface(self, ux, uy, p, nu):
        """The surface terms of ``F_x`` at the state, and their gradients
        ``(∂/∂ux, ∂/∂uy, ∂/∂p, ∂/∂ν)``."""
        dx, dy = self.dx, self.dy
        i0, i1, j0, j1 = self.i0, self.i1, self.j0, self.j1
        gux, guy, gp = np.zeros_like(ux), np.zeros_like(uy), np.zeros_like(p)
        f, fnu = 0.0, 0.0
        J = slice(j0, j1)
        for i, n in ((i0, -1.0), (i1, 1.0)):
            pf = 0.5 * (p[i - 1, J] + p[i, J])
            un = ux[i, J]
            dudx = (ux[i + 1, J] - ux[i - 1, J]) / (2.0 * dx)
            f += n * dy * float(np.sum(-pf + nu * dudx - un * un))
            fnu += n * dy * float(np.sum(dudx))
            gp[i - 1, J] -= 0.5 * n * dy
            gp[i, J] -= 0.5 * n * dy
            gux[i + 1, J] += n * dy * nu / (2.0 * dx)
            gux[i - 1, J] -= n * dy * nu / (2.0 * dx)
            gux[i, J] -= 2.0 * n * dy * un
        I, I1 = slice(i0, i1), slice(i0 + 1, i1 + 1)
        for j, n in ((j0, -1.0), (j1, 1.0)):
            lo = 0.5 * (ux[I, j - 1] + ux[I1, j - 1])  # cell-centred u_x below the edge
            hi = 0.5 * (ux[I, j] + ux[I1, j])  # and above it
            vn = uy[I, j]
            uf = 0.5 * (lo + hi)
            dudy = (hi - lo) / dy
            f += n * dx * float(np.sum(nu * dudy - uf * vn))
            fnu += n * dx * float(np.sum(dudy))
            g_hi = n * dx * (nu / dy - 0.5 * vn)
            g_lo = n * dx * (-nu / dy - 0.5 * vn)
            guy[I, j] -= n * dx * uf
            for jj, g in ((j - 1, g_lo), (j, g_hi)):
                gux[I, jj] += 0.5 * g
                gux[I1, jj] += 0.5 * g
        return f, (gux, guy, gp, fnu)

    def momentum(self, ux):
        """``∫ u_x dV`` over the box (cell-centred ``u_x``) and its gradient."""
        I, I1, J = slice(self.i0, self.i1), slice(self.i0 + 1, self.i1 + 1), slice(self.j0, self.j1)
        w = 0.5 * self.dx * self.dy
        g = np.zeros_like(ux)
        g[I, J] += w
        g[I1, J] += w
        return float(np.sum(g * ux)), g


class _Drag:
    """Mosaic's drag (the entrants' convention): minus the mean x-force of
    the flow on the body over the last ``m`` steps (the force on the fluid,
    negative for flow in +x). On the staircase the force is diffphys'
    surface integral of each step's end state (``FlowStep``'s ``force``,
    seeded through ``grad_force``); on the immersed circle the momentum
    balance over a box about it (``_ControlVolume``): the mean over the tail
    of the surface terms of each step's end state, and the momentum change
    inside the box over the tail, ``−(M_m − M_0) / (m dt)``, both functions
    of the states, seeded through the state gradients."""

    def __init__(self, scene, circle, extent: float):
        self.cv = None if BODY == "staircase" else _ControlVolume(scene, circle, extent)
        self.dt = scene.dt

    def value(self, states, forces, nu) -> float:
        """The drag of the tail ``states`` ``s_0 .. s_m`` (``s_0`` entering
        the first tail step) and the forces ``forces`` reported by each."""
        m = len(forces)
        if self.cv is None:
            return -sum(float(f[0]) for f in forces) / m
        fx = sum(self.cv.surface(vx, vy, p, nu)[0] for vx, vy, p in states[1:]) / m
        dm = self.cv.momentum(states[-1][0])[0] - self.cv.momentum(states[0][0])[0]
        return -(fx - dm / (m * self.dt))

    def seeds(self, k, state, m, gd, nu):
        """The cotangents ``(ux, uy, P, force, ν)`` that ``gd * drag`` puts
        on the tail state ``s_k`` (``k`` in ``0..m``; ``force`` and the
        state's terms for ``k >= 1``, where ``s_k`` is a step's output)."""
        vx, vy, p = state
        zero = (np.zeros_like(vx), np.zeros_like(vy), np.zeros_like(p))
        if self.cv is None:
            force = None if k == 0 else np.array([-gd / m, 0.0], vx.dtype)
            return (*zero, force, 0.0)
        gux, guy, gp, gnu = zero[0], zero[1], zero[2], 0.0
        if k >= 1:
            _, (sux, suy, sp, snu) = self.cv.surface(vx, vy, p, nu)
            gux, guy, gp, gnu = -gd / m * sux, -gd / m * suy, -gd / m * sp, -gd / m * snu
        if k in (0, m):
            _, gm = self.cv.momentum(vx)
            gux = gux + (1.0 if k == m else -1.0) * gd / (m * self.dt) * gm
        return gux, guy, gp, None, gnu


def _force_column(vx, column):
    """The x-faces with the face column x = 0 set to ``column``."""
    vx = vx.copy()
    vx[0, :] = column
    return vx


def _advance(scene, vx, vy, p, k: int, nu: float, kw: dict, column=None):
    """``k`` steps from ``(vx, vy, p)``: ``(vx', vy', p', force)``; with a
    ``column``, one step at a time, each from the state with its x = 0 face
    column set to it."""
    if column is None:
        return scene.forward(vx, vy, steps=k, pressure=p, viscosity=nu, **kw)
    f = None
    for _ in range(k):
        vx, vy, p, f = scene.forward(_force_column(vx, column), vy, steps=1, pressure=p,
                                     viscosity=nu, **kw)
    return vx, vy, p, f


def _rollout(scene, ux, uy, steps: int, nu: float, kw: dict, drag=None, column=None):
    """``steps`` steps from the faces ``(ux, uy)`` (pressure zero): the end
    faces, the tail states ``s_0 .. s_m`` ``(ux, uy, P)`` of the last ``m =
    _tail(steps)`` steps (``s_0`` entering the first of them; None without
    an obstacle), and the drag (``_Drag``; 0 without an obstacle). With a
    ``column`` (the forced-column inflow) every step starts from the state
    with its x = 0 face column set to it."""
    if drag is None:
        vx, vy, _, _ = _advance(scene, ux, uy, None, steps, nu, kw, column)
        return vx, vy, None, 0.0
    m = _tail(steps)
    if steps > m:
        vx, vy, p, _ = _advance(scene, ux, uy, None, steps - m, nu, kw, column)
    else:
        vx, vy, p = ux, uy, np.zeros(scene.shape, ux.dtype)
    states, forces = [(vx, vy, p)], []
    for _ in range(m):
        vx, vy, p, f = _advance(scene, vx, vy, p, 1, nu, kw, column)
        states.append((vx, vy, p))
        forces.append(f)
    return vx, vy, states, drag.value(states, forces, nu)


def _vjp_column(scene, ux, uy, gx, gy, gd: float, steps: int, nu: float, drag, column):
    """The gradients ``(ux, uy, P, viscosity, wall_speed, column)`` of
    ``<gx, ux'> + <gy, uy'> + gd * drag`` through ``steps`` steps of the
    forced-column inflow: every step recorded, then one single-step VJP per
    step in reverse, each at the state with its column set, the column's
    faces' gradient moved to the profile (setting a face is the adjoint's
    zeroing it and adding its gradient to the value it was set to)."""
    states = [(ux, uy, np.zeros(scene.shape, ux.dtype))]
    forces = []
    for _ in range(steps):
        vx, vy, p, f = _advance(scene, *states[-1], 1, nu, {}, column)
        states.append((vx, vy, p))
        forces.append(f)
    m = _tail(steps) if drag is not None else 0
    if gx is None:
        gx, gy = np.zeros(scene.shape_x, ux.dtype), np.zeros(scene.shape_y, ux.dtype)
    gp = np.zeros(scene.shape, ux.dtype)
    gnu, gcol = 0.0, np.zeros_like(column)
    for i in range(steps, 0, -1):
        sforce = None
        k = i - (steps - m)  # the tail index of the state s_i
        if drag is not None and gd != 0.0 and k >= 1:
            sux, suy, sp, sforce, snu = drag.seeds(k, states[i], m, gd, nu)
            gx, gy, gp, gnu = gx + sux, gy + suy, gp + sp, gnu + snu
        vx, vy, p = states[i - 1]
        g = scene.vjp(_force_column(vx, column), vy, gx, gy, gp, sforce, steps=1, pressure=p,
                      viscosity=nu, checkpoint_every=1)
        gx, gy, gp = g[0].copy(), g[1], g[2]
        gnu += g[3]
        gcol += gx[0, :]
        gx[0, :] = 0.0
        if drag is not None and gd != 0.0 and i - 1 == steps - m:
            sux, suy, sp, _, _ = drag.seeds(0, states[i - 1], m, gd, nu)
            gx, gy, gp = gx + sux, gy + suy, gp + sp
    return gx, gy, None, gnu, None, gcol


def _forward(raw: dict):
    """The collocated result ``(N, N, 2)`` and the drag (``_rollout``) of
    the (dumped) inputs ``raw``, in the solver's precision (``apply`` casts
    them to float32; fd checks in float64 call this with float64 inputs)."""
    scene, v0, nu, lay, drag = _setup(raw)
    ux, uy = _zero_solid(scene, lay, *_to_faces(v0, lay))
    kw = {} if lay.q is None else {"inflow": lay.q}
    vx, vy, _, d = _rollout(scene, ux, uy, int(raw["steps"]), nu, kw, drag, lay.column)
    return _to_cells(vx, vy, lay), d


# The scene whose FlowStep keeps its last VJP's buffers (the tape's memory,
# reused by the next call instead of faulted in afresh: a third of a call at
# 256²). Only one at a time: the cached scenes of other sizes give theirs
# back when another scene's VJP runs.
_buffers_kept_by = None


def _keep_buffers_of(scene) -> None:
    global _buffers_kept_by
    if _buffers_kept_by is not None and _buffers_kept_by is not scene:
        _buffers_kept_by.release_buffers()
    _buffers_kept_by = scene


def _vjp_tail_drag(scene, ux, uy, gx, gy, gd: float, steps: int, nu: float, kw: dict, drag):
    """``FlowStep.vjp``'s gradients ``(ux, uy, P, viscosity, wall_speed,
    inflow)`` of ``<gx, ux'> + <gy, uy'> + gd * drag`` with the drag of
    ``_rollout``: the last ``m`` steps one at a time from their recorded
    states, each output state getting the cotangents ``_Drag.seeds`` puts on
    it, then the first ``steps - m`` steps in one VJP (every step kept on
    the tape)."""
    _, _, states, _ = _rollout(scene, ux, uy, steps, nu, kw, drag)
    m = len(states) - 1
    if gx is None:
        gx, gy = np.zeros(scene.shape_x, ux.dtype), np.zeros(scene.shape_y, ux.dtype)
    gp = np.zeros(scene.shape, ux.dtype)
    gnu, gq = 0.0, None
    for k in range(m, 0, -1):
        sux, suy, sp, sforce, snu = drag.seeds(k, states[k], m, gd, nu)
        vx, vy, p = states[k - 1]
        g = scene.vjp(vx, vy, gx + sux, gy + suy, gp + sp, sforce, steps=1, pressure=p,
                      viscosity=nu, checkpoint_every=1, **kw)
        gx, gy, gp = g[0], g[1], g[2]
        gnu += g[3] + snu
        gq = g[5] if gq is None else gq + g[5]
    sux, suy, sp, _, _ = drag.seeds(0, states[0], m, gd, nu)
    gx, gy, gp = gx + sux, gy + suy, gp + sp
    if steps > m:
        g = scene.vjp(ux, uy, gx, gy, gp, None, steps=steps - m, viscosity=nu,
                      checkpoint_every=1, **kw)
        gx, gy = g[0], g[1]
        gnu += g[3]
        gq = gq + g[5]
    # the initial pressure is zero, not an input: its gradient is dropped
    return gx, gy, None, gnu, None, gq


def _vjp(raw: dict, vjp_inputs, vjp_outputs, cotangent_vector) -> dict:
    """The gradients of ``vector_jacobian_product`` in the solver's
    precision (``v0`` as ``(N, N, 2)``, ``viscosity`` a float,
    ``inflow_profile`` its own length)."""
    scene, v0, nu, lay, drag = _setup(raw)
    if "inflow_profile" in vjp_inputs and not lay.profile_given:
        raise ValueError("diffphys' adapter: a gradient for inflow_profile, which was not given")
    ux, uy = _zero_solid(scene, lay, *_to_faces(v0, lay))
    g_result = cotangent_vector.get("result") if "result" in vjp_outputs else None
    g_drag = cotangent_vector.get("drag") if "drag" in vjp_outputs else None
    gx = gy = None
    if g_result is not None:
        gx, gy = _to_cells_t(np.asarray(g_result, DTYPE)[:, :, 0, :], lay)
    kw = {} if lay.q is None else {"inflow": lay.q}
    _keep_buffers_of(scene)
    steps = int(raw["steps"])
    gd = 0.0 if g_drag is None else float(np.asarray(g_drag).reshape(-1)[0])
    if lay.column is not None:
        g = _vjp_column(scene, ux, uy, gx, gy, gd, steps, nu, drag, lay.column)
    elif gd == 0.0 or drag is None:
        # every step kept on the tape, as JAX's scan keeps its residuals (100
        # steps at 256² in f64: about 470 MB); no recomputation in the
        # reverse sweep
        g = scene.vjp(ux, uy, gx, gy, None, None, steps=steps, viscosity=nu,
                      checkpoint_every=1, **kw)
    else:
        g = _vjp_tail_drag(scene, ux, uy, gx, gy, gd, steps, nu, kw, drag)
    out = {}
    if "v0" in vjp_inputs:
        gux, guy = _zero_solid(scene, lay, g[0], g[1])
        out["v0"] = _to_faces_t(gux, guy, lay)
    if "viscosity" in vjp_inputs:
        out["viscosity"] = g[3]
    if "inflow_profile" in vjp_inputs:
        gq = np.asarray(g[5], np.float64)
        out["inflow_profile"] = gq if lay.resample is None else lay.resample.T @ gq
    return out


def apply(inputs: InputSchema) -> dict:
    """Run ``steps`` diffphys flow steps from ``v0``."""
    result, drag = _forward(inputs.model_dump())
    return {"result": result[:, :, None, :].astype(np.float32),
            "drag": np.array([drag], np.float32)}


def vector_jacobian_product(
    inputs: InputSchema,
    vjp_inputs: set[str],
    vjp_outputs: set[str],
    cotangent_vector: dict[str, Any],
) -> dict:
    """``(∂L/∂v0, ∂L/∂viscosity, ∂L/∂inflow_profile)`` from the cotangents of
    ``result`` and ``drag``."""
    g = _vjp(inputs.model_dump(), vjp_inputs, vjp_outputs, cotangent_vector)
    out = {}
    if "v0" in g:
        out["v0"] = g["v0"][:, :, None, :].astype(np.float32)
    if "viscosity" in g:
        out["viscosity"] = np.array([g["viscosity"]], np.float32)
    if "inflow_profile" in g:
        out["inflow_profile"] = g["inflow_profile"].astype(np.float32)
    return out


def abstract_eval(abstract_inputs: InputSchema) -> dict:
    """``result`` has the shape of ``v0``; ``drag`` is ``(1,)``."""
    v0 = abstract_inputs.model_dump()["v0"]
    shape = tuple(v0["shape"]) if isinstance(v0, dict) else np.shape(v0)
    return {
        "result": {"shape": shape, "dtype": "float32"},
        "drag": {"shape": (1,), "dtype": "float32"},
    }
