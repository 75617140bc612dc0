"""What a drag_opt run (``mosaic_run.py run -e optimization/drag_opt -o DIR``)
did, read back from its files, and its initial and final profiles' drags by
both force methods. Run it with the same ``DIFFPHYS_TESSERACT_BODY`` and
``DIFFPHYS_TESSERACT_INFLOW`` as the run:

    python benches/mosaic/drag_opt_forces.py DIR

Prints one JSON object:

* ``reduction_at``: the drag reduction (%) at iterations 50, 100, 150, 200
  and the last, and its rate per iteration over the last 50 (from the run's
  ``result.json``);
* ``profile_change``: the median, largest and smallest |final − initial|
  of the 32 profile values (Adam at 5e-4 moves each by at most about
  5e-4 per iteration);
* ``drags``: for the initial and the final profile (``profiles.npz``),
  the adapter's drag, the momentum balance over square boxes of
  half-width 0.15 to 0.30 about the cylinder, and, on an immersed circle,
  minus the tail mean of the forcing's momentum exchange (the force
  ``FlowStep`` reports for an immersed scene, not on the tape), each with
  the reduction it gives; the exchange force of the first and last tail
  step of the initial profile (steady or not);
* ``centre_line_ux``: u_x on the centre line (cell rows 15-16) in cell
  columns 0, 2, 5, 31 of the initial flow (``flow_fields.npz``): the flow
  that reaches the cylinder, and what re-enters a periodic box.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

ADAPTER = (Path(__file__).resolve().parent / "entry" / "navier-stokes-grid" / "diffphys"
           / "tesseract_api.py")


def _adapter():
    spec = importlib.util.spec_from_file_location("diffphys_mosaic_adapter", ADAPTER)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _inputs(run: dict, profile: np.ndarray) -> dict:
    """drag_opt's inputs as its ``make_inputs`` builds them, for ``profile``."""
    phys = run["physics"]
    n = phys["N"]
    faces = {k: {"type": "periodic", "value": None}
             for k in ("x_lo", "x_hi", "z_lo", "z_hi")}
    faces.update({k: {"type": "no_slip", "value": None} for k in ("y_lo", "y_hi")})
    v0 = np.zeros((n, n, 1, 2))
    v0[..., 0] = phys["U_mean"]
    return {"v0": v0, "viscosity": [phys["nu"]], "dt": [phys["dt"]], "steps": phys["steps"],
            "domain_extent": phys["domain_extent"], "inflow_profile": profile,
            "obstacle": phys["obstacle"], "boundary_conditions": faces}


def _box_drag(ta, states, n: int, half: float, nu: float, dt: float) -> float:
    """The tail drag by the momentum balance over the square of half-width
    ``half`` about the centre of the unit box."""
    cv = ta._ControlVolume.__new__(ta._ControlVolume)
    cv.dx = cv.dy = 1.0 / n
    cv.i0 = cv.j0 = int(round((0.5 - half) * n))
    cv.i1 = cv.j1 = int(round((0.5 + half) * n))
    m = len(states) - 1
    surface = np.mean([cv.surface(a, b, p, nu)[0] for a, b, p in states[1:]])
    dm = cv.momentum(states[-1][0])[0] - cv.momentum(states[0][0])[0]
    return float(-(surface - dm / (m * dt)))


def main(root: Path) -> dict:
    ta = _adapter()
    exp = next(root.glob("**/optimization/drag_opt/result.json"))
    result = json.loads(exp.read_text())
    run = json.loads((exp.parent / "params.json").read_text())
    run = run.get("params", run)
    drags = np.abs(np.array(result["results"][0]["metrics"]["drags"]))
    red = 100 * (drags[0] - drags) / drags[0]
    last = len(red) - 1
    out = {"body": ta.BODY, "inflow": ta.INFLOW,
           "reduction_at": {str(i): round(float(red[i]), 2) for i in (50, 100, 150, 200, last)
                            if i <= last},
           "reduction_per_iteration_last_50": round(float(red[last] - red[last - 50]) / 50, 4)}
    prof = np.load(exp.parent / "profiles.npz")
    change = np.abs(prof["final_diffphys"] - prof["initial"])
    out["profile_change"] = {"median": float(np.median(change)), "max": float(change.max()),
                             "min": float(change.min())}
    n = run["physics"]["N"]
    nu, dt = run["physics"]["nu"], run["physics"]["dt"]
    rows = {}
    for name in ("initial", "final_diffphys"):
        raw = _inputs(run, prof[name].astype(np.float64))
        scene, v0, nu_, lay, drag = ta._setup(raw)
        ux, uy = ta._zero_solid(scene, lay, *ta._to_faces(v0, lay))
        kw = {} if lay.q is None else {"inflow": lay.q}
        _, _, states, d = ta._rollout(scene, ux, uy, raw["steps"], nu_, kw, drag, lay.column)
        row = {"adapter": d}
        for half in (0.15, 0.2, 0.25, 0.3):
            row[f"box {half}"] = _box_drag(ta, states, n, half, nu, dt)
        if drag.cv is not None:
            # the step from each tail state again, for its exchange force
            forces = [ta._advance(scene, a, b, p, 1, nu_, kw, lay.column)[3][0]
                      for a, b, p in states[:-1]]
            row["exchange"] = -float(np.mean(forces))
            if name == "initial":
                out["initial_exchange_force_first_last_tail_step"] = [float(forces[0]),
                                                                      float(forces[-1])]
        rows[name] = row
    out["drags"] = {k: {"initial": rows["initial"][k], "final": rows["final_diffphys"][k],
                        "reduction_pct": 100 * (abs(rows["initial"][k])
                                                - abs(rows["final_diffphys"][k]))
                        / abs(rows["initial"][k])}
                    for k in rows["initial"]}
    flow = np.load(exp.parent / "flow_fields.npz")
    u = np.asarray(flow["flow_initial_diffphys"])[:, :, 0, 0]
    out["centre_line_ux"] = {str(i): round(float(u[i, 15:17].mean()), 3) for i in (0, 2, 5, 31)}
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    print(json.dumps(main(Path(sys.argv[1]))))
