"""Where our forward/tgv_nu_sweep error comes from: Mosaic's Taylor-Green
case (its ``tgv`` initial condition and analytic solution, N = 64, domain
2 pi, dt = 0.05, 20 steps) through diffphys' flow step directly, with the
advection (semi-Lagrangian, the adapter's; MacCormack) crossed with the
collocated <-> face conversion (the adapter's two-point average; a
four-point, fourth-order one, (-1, 9, 9, -1) / 16 both ways), and the
time of a 100-step VJP at N = 128 for each advection (best of 3). Nothing
here changes the adapter: it measures what each choice would give.

    python benches/mosaic/tgv_schemes.py

Prints one JSON line and writes it to benches/mosaic/tgv_schemes.json.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import mosaic
import numpy as np

sys.path.insert(0, str(Path(mosaic.__file__).parent))

import diffphys as dp  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from mosaic.benchmarks.problems.navier_stokes_grid.ics import _tgv, _tgv_analytic  # noqa: E402

OUT = Path(__file__).resolve().parent / "tgv_schemes.json"


def faces2(c, ax):
    return 0.5 * (np.roll(c, 1, axis=ax) + c)


def cells2(f, ax):
    return 0.5 * (f + np.roll(f, -1, axis=ax))


def faces4(c, ax):  # face a between cells a-1 and a
    r = lambda k: np.roll(c, k, axis=ax)  # noqa: E731
    return (-r(2) + 9 * r(1) + 9 * c - r(-1)) / 16


def cells4(f, ax):  # cell i between faces i and i+1
    r = lambda k: np.roll(f, k, axis=ax)  # noqa: E731
    return (-r(1) + 9 * f + 9 * r(-1) - r(-2)) / 16


def main() -> None:
    n, L, dt, steps = 64, 2 * np.pi, 0.05, 20
    ic = np.asarray(_tgv(n, L=L), np.float64)
    rows = []
    for adv in ("semi_lagrangian", "maccormack"):
        for conv, (tf, tc) in (("two-point", (faces2, cells2)), ("four-point", (faces4, cells4))):
            for nu in (1e-4, 1e-2, 5e-2):
                scene = dp.FlowStep((n, n), (L, L), sides="periodic", viscosity=nu, dt=dt,
                                    pressure_solver="fourier", substepping=True, advection=adv)
                vx, vy, _, _ = scene.forward(tf(ic[:, :, 0, 0], 0), tf(ic[:, :, 0, 1], 1),
                                             steps=steps)
                res = np.stack([tc(vx, 0), tc(vy, 1)], -1)
                ref = np.asarray(_tgv_analytic(jnp.asarray(ic), nu, dt * steps, L=L))[:, :, 0, :]
                rows.append({"advection": adv, "conversion": conv, "nu": nu,
                             "error": float(np.linalg.norm(res - ref) / np.linalg.norm(ref))})
    m = 128
    x = np.linspace(0, L, m, endpoint=False)
    ux = 0.5 * np.sin(x)[:, None] * np.cos(x)[None, :]
    uy = -0.5 * np.cos(x)[:, None] * np.sin(x)[None, :]
    vjp_s = {}
    scenes = {adv: dp.FlowStep((m, m), (L, L), sides="periodic", viscosity=0.01, dt=0.01,
                               pressure_solver="fourier", substepping=True, advection=adv)
              for adv in ("semi_lagrangian", "maccormack")}
    for _ in range(3):
        for adv, scene in scenes.items():
            t = time.perf_counter()
            scene.vjp(ux, uy, ux, uy, steps=100, checkpoint_every=1)
            vjp_s.setdefault(adv, []).append(time.perf_counter() - t)
    out = {"check": "tgv_schemes", "n": n, "dt": dt, "steps": steps, "rows": rows,
           "vjp_100_steps_n128_s": {k: min(v) for k, v in vjp_s.items()},
           "vjp_ratio_maccormack_over_semi_lagrangian":
               min(vjp_s["maccormack"]) / min(vjp_s["semi_lagrangian"])}
    s = json.dumps(out)
    OUT.write_text(s + "\n")
    print(s)


if __name__ == "__main__":
    main()
