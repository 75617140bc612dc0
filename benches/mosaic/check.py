"""A first check of benches/mosaic/entry/navier-stokes-grid/diffphys/tesseract_api.py through tesseract-core,
in-process (no Docker): apply on Mosaic's default vortex initial condition,
and the VJP against central differences along random directions (Mosaic's
fd_check criteria: cosine >= 0.99 and median relative error <= 1e-3).

This is not Mosaic's experiment runner (mosaic run -p ns-grid ...), which
discovers its solvers from its own package and Docker images; wiring our
in-process Tesseract into it is still to do (see the report in docs).

    pip install mosaic-bench==0.2.0
    python benches/mosaic/check.py [--n 32] [--steps 20] [--directions 6] [--eps 1e-3]

The schema's outputs are float32: the loss carries a rounding error of about
1e-7 of its size, which central differences divide by 2·eps. At N = 64 and
100 steps, eps = 1e-3 gives a median relative error of 4.9e-3 (cosine
0.999997) and eps = 1e-2 gives 2.7e-4 (cosine 0.99999998) for the same VJP:
the difference is the differences' rounding, not the gradient
(benches/mosaic/check.json; the VJP itself passes torch's gradcheck in
float64, crates/python/tests/test_flow.py).

Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import time


import sys
from pathlib import Path as _Path

import mosaic
import numpy as np

# Mosaic's Tesseracts import its shared schemas as the top-level package
# mosaic_shared (their images copy it beside them); in-process it sits inside
# the installed mosaic package.
sys.path.insert(0, str(_Path(mosaic.__file__).parent))

from mosaic_shared.problems.navier_stokes_grid.schemas import make_vortex_ic
from tesseract_core import Tesseract

API = _Path(__file__).resolve().parent / "entry" / "navier-stokes-grid" / "diffphys" / "tesseract_api.py"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--directions", type=int, default=6)
    ap.add_argument("--eps", type=float, default=1e-3)
    args = ap.parse_args()
    t = Tesseract.from_tesseract_api(str(API))
    v0 = make_vortex_ic(N=args.n, L=2 * np.pi, seed=42)
    base = {"v0": v0, "viscosity": np.array([0.05], np.float32),
            "dt": np.array([0.01], np.float32), "steps": args.steps}
    t0 = time.perf_counter()
    out = t.apply(base)
    apply_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    w = rng.standard_normal(np.shape(out["result"])).astype(np.float32)
    t0 = time.perf_counter()
    g = t.vector_jacobian_product(base, vjp_inputs=["v0"], vjp_outputs=["result"],
                                  cotangent_vector={"result": w})["v0"]
    vjp_s = time.perf_counter() - t0

    def loss(v):
        r = t.apply(dict(base, v0=v))["result"]
        return float(np.sum(w.astype(np.float64) * np.asarray(r, np.float64)))

    ad, fd = [], []
    for _ in range(args.directions):
        d = rng.standard_normal(v0.shape).astype(np.float32)
        d /= np.linalg.norm(d)
        ad.append(float(np.sum(np.asarray(g, np.float64) * d)))
        fd.append((loss(v0 + args.eps * d) - loss(v0 - args.eps * d)) / (2 * args.eps))
    ad, fd = np.array(ad), np.array(fd)
    cosine = float(ad @ fd / (np.linalg.norm(ad) * np.linalg.norm(fd)))
    rel = np.abs(ad - fd) / np.maximum(np.abs(fd), 1e-30)
    print(json.dumps({
        "check": "mosaic_tesseract_fd", "n": args.n, "steps": args.steps,
        "apply_s": apply_s, "vjp_s": vjp_s, "cosine": cosine,
        "median_rel_error": float(np.median(rel)), "directional_ad": ad.tolist(),
        "directional_fd": fd.tolist(),
        "passes_mosaic_thresholds": bool(cosine >= 0.99 and np.median(rel) <= 1e-3),
    }))


if __name__ == "__main__":
    main()
