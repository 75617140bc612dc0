"""Does the adapter's advection make drag_opt's Re 20 flow? Two measurements
of each advection (``semi_lagrangian``, the adapter's default; ``maccormack``,
limited), nothing in the adapter changed by them:

* ``refinement``: drag_opt's initial flow (flat profile 0.5, the immersed
  circle of radius 0.05, the inflow/outflow channel, nu = 0.0025, t = 4)
  at N = 32, 64, 128, 256 with dt = 0.02 * 32 / N (the Courant number
  U dt / h = 0.32 of Mosaic's N = 32 at every N) and 200 * N / 32 steps;
  its drag as the adapter reports it (the tail mean over the last half of
  the steps, the momentum balance over the adapter's box) and by the same
  balance over a fixed box of half-width 0.2, with c_D = |drag| / (U^2 D / 2);
* ``tgv``: the effective viscosity of a Taylor-Green mode
  (u = U sin(2 pi x) cos(2 pi y), v = -U cos(2 pi x) sin(2 pi y), U = 0.5)
  in the unit periodic box at N = 32, dt = 0.02 (Courant number 0.32 at the
  peak speed), 200 steps, from the decay of the mode's amplitude
  a(t) = a(0) exp(-2 k^2 nu_eff t), k = 2 pi, at nu = 0.0025 and nu = 1e-9
  (the numerical part alone).

* ``sensitivity``: at N = 32 (Mosaic's drag_opt, flat profile) the drag's
  gradient to the profile, and what a first Adam step (each value moved by
  the learning rate 5e-4 against its gradient's sign) and a change of 0.125
  (250 such steps) would take off |drag| to first order, in %.

    python benches/mosaic/drag_opt_advection.py              # all three
    python benches/mosaic/drag_opt_advection.py sensitivity  # the last only,
                                                             # into the file

Prints one JSON line and writes it to benches/mosaic/drag_opt_advection.json.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import diffphys as dp  # noqa: E402
from drag_opt_forces import _adapter, _box_drag  # noqa: E402

OUT = Path(__file__).resolve().parent / "drag_opt_advection.json"
SCHEMES = ("semi_lagrangian", "maccormack")
U, D, NU = 0.5, 0.1, 0.0025


def _inputs(n: int) -> dict:
    """drag_opt's inputs (its ``make_inputs``, flat profile) at ``n`` cells
    and the Courant number of Mosaic's N = 32."""
    faces = {k: {"type": "periodic", "value": None} for k in ("x_lo", "x_hi", "z_lo", "z_hi")}
    faces.update({k: {"type": "no_slip", "value": None} for k in ("y_lo", "y_hi")})
    v0 = np.zeros((n, n, 1, 2))
    v0[..., 0] = U
    return {"v0": v0, "viscosity": [NU], "dt": [0.02 * 32 / n], "steps": 200 * n // 32,
            "domain_extent": 1.0, "inflow_profile": np.full(n, U),
            "obstacle": {"shape": "cylinder", "center": [0.5, 0.5], "radius": D / 2},
            "boundary_conditions": faces}


def refinement(ta, scheme: str, n: int) -> dict:
    ta.BODY, ta.ADVECTION = "immersed", scheme
    raw = _inputs(n)
    t = time.perf_counter()
    scene, v0, nu, lay, drag = ta._setup(raw)
    ux, uy = ta._zero_solid(scene, lay, *ta._to_faces(v0, lay))
    kw = {} if lay.q is None else {"inflow": lay.q}
    _, _, states, d = ta._rollout(scene, ux, uy, raw["steps"], nu, kw, drag, lay.column)
    box = _box_drag(ta, states, n, 0.2, NU, raw["dt"][0])
    q = 0.5 * U * U * D
    return {"advection": scheme, "n": n, "dt": raw["dt"][0], "steps": raw["steps"],
            "drag": d, "c_d": abs(d) / q, "drag_box_0.2": box, "c_d_box_0.2": abs(box) / q,
            "seconds": time.perf_counter() - t}


def tgv(scheme: str, nu: float, n: int = 32, dt: float = 0.02, steps: int = 200) -> dict:
    k = 2 * np.pi
    h = 1.0 / n
    xf, xc = np.arange(n) * h, (np.arange(n) + 0.5) * h
    mode_x = np.sin(k * xf)[:, None] * np.cos(k * xc)[None, :]  # u on the x faces
    mode_y = -np.cos(k * xc)[:, None] * np.sin(k * xf)[None, :]  # v on the y faces
    scene = dp.FlowStep((n, n), (1.0, 1.0), sides="periodic", viscosity=nu, dt=dt,
                        pressure_solver="fourier", substepping=True, advection=scheme)
    vx, vy, _, _ = scene.forward(U * mode_x, U * mode_y, steps=steps)
    norm = (mode_x ** 2).sum() + (mode_y ** 2).sum()
    a = float(((vx * mode_x).sum() + (vy * mode_y).sum()) / norm)
    t_end = dt * steps
    nu_eff = -np.log(a / U) / (2 * k * k * t_end)
    return {"advection": scheme, "nu": nu, "n": n, "dt": dt, "steps": steps,
            "amplitude_ratio": a / U, "exact_ratio": float(np.exp(-2 * k * k * nu * t_end)),
            "nu_eff": float(nu_eff), "nu_numerical": float(nu_eff - nu)}


def sensitivity(ta, scheme: str) -> dict:
    ta.BODY, ta.ADVECTION = "immersed", scheme
    raw = _inputs(32)
    d = ta._forward(raw)[1]
    g = ta._vjp(raw, {"inflow_profile"}, {"drag"}, {"drag": np.array([1.0])})["inflow_profile"]
    l1 = float(np.abs(g).sum())
    return {"advection": scheme, "drag": d, "grad_l1": l1,
            "first_step_pct": 100 * 5e-4 * l1 / abs(d), "change_0.125_pct": 100 * 0.125 * l1 / abs(d)}


def main() -> None:
    ta = _adapter()
    if sys.argv[1:] == ["sensitivity"]:
        out = json.loads(OUT.read_text())
        out["sensitivity"] = [sensitivity(ta, s) for s in SCHEMES]
        line = json.dumps(out)
        OUT.write_text(line + "\n")
        print(line)
        return
    out = {"check": "drag_opt_advection", "U": U, "D": D, "nu": NU,
           "tgv": [tgv(s, nu) for s in SCHEMES for nu in (NU, 1e-9)], "refinement": []}
    print(json.dumps(out["tgv"]), flush=True)
    for n in (32, 64, 128, 256):
        for s in SCHEMES:
            out["refinement"].append(refinement(ta, s, n))
            print(json.dumps(out["refinement"][-1]), flush=True)
    out["sensitivity"] = [sensitivity(ta, s) for s in SCHEMES]
    line = json.dumps(out)
    OUT.write_text(line + "\n")
    print(line)


if __name__ == "__main__":
    main()
