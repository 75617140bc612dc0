"""VJP cost of 100 steps, diffphys' Tesseract against Mosaic's own JAX-CFD
Tesseract, both in-process in one run (``pip install mosaic-bench==0.2.0
jax-cfd==0.2.1 equinox``): Mosaic's vortex initial condition, ν = 0.05,
dt = 0.01, cotangent on ``result``. The first call of each (JAX-CFD's
includes its JIT compilation) is reported apart; then ``--repeats`` rounds,
the two alternating within each round, best and spread.

    python benches/mosaic/vjp_cost.py [--sizes 64,128] [--repeats 3]

Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import mosaic
import numpy as np

sys.path.insert(0, str(Path(mosaic.__file__).parent))

from mosaic_shared.problems.navier_stokes_grid.schemas import make_vortex_ic  # noqa: E402
from tesseract_core import Tesseract  # noqa: E402

OURS = Path(__file__).resolve().parent / "entry" / "navier-stokes-grid" / "diffphys" / "tesseract_api.py"
JAX_CFD = Path(mosaic.__file__).parent / "tesseracts/navier-stokes-grid/jax-cfd/tesseract_api.py"
EXTRA = {"jax_cfd": {"density": np.array([1.0], np.float32), "inner_steps": 1}, "diffphys": {}}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="64,128")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--steps", type=int, default=100)
    args = ap.parse_args()
    solvers = {"diffphys": Tesseract.from_tesseract_api(str(OURS)),
               "jax_cfd": Tesseract.from_tesseract_api(str(JAX_CFD))}
    out = {"bench": "mosaic_vjp_cost", "steps": args.steps, "loadavg_before": os.getloadavg(),
           "sizes": {}}
    for n in map(int, args.sizes.split(",")):
        v0 = make_vortex_ic(N=n, L=2 * np.pi, seed=42)
        w = np.random.default_rng(0).standard_normal(v0.shape).astype(np.float32)
        base = {"v0": v0, "viscosity": np.array([0.05], np.float32),
                "dt": np.array([0.01], np.float32), "steps": args.steps}

        def vjp(name):
            t0 = time.perf_counter()
            g = solvers[name].vector_jacobian_product(
                dict(base, **EXTRA[name]), vjp_inputs=["v0"], vjp_outputs=["result"],
                cotangent_vector={"result": w})
            return time.perf_counter() - t0, np.asarray(g["v0"], np.float64)

        first = {k: vjp(k) for k in solvers}
        times = {k: [] for k in solvers}
        for _ in range(args.repeats):
            for k in solvers:
                times[k].append(vjp(k)[0])
        ga, gb = first["diffphys"][1], first["jax_cfd"][1]
        r = {k: {"first_s": first[k][0], "best_s": min(v), "spread": (max(v) - min(v)) / min(v),
                 "runs_s": v} for k, v in times.items()}
        r["ratio_diffphys_over_jax_cfd"] = r["diffphys"]["best_s"] / r["jax_cfd"]["best_s"]
        r["gradient_cosine"] = float(ga.ravel() @ gb.ravel() / (np.linalg.norm(ga) * np.linalg.norm(gb)))
        # a gradient with NaN or infinity (an unstable run) measured nothing
        for k, g in (("diffphys", ga), ("jax_cfd", gb)):
            r[k]["gradient_finite"] = bool(np.isfinite(g).all())
        out["sizes"][str(n)] = r
    out["loadavg_after"] = os.getloadavg()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
