"""Mosaic's forward/baseline on diffphys' Tesseract, in-process, with Mosaic's
own initial condition, analytic reference and error function: the
Taylor-Green vortex on [0, 2π]², ν = 0.05, dt = 0.01, one step, N = 16, 32,
64, 128, error ``l2_error_rel`` against ``_tgv_analytic`` at t = dt.

    python benches/mosaic/baseline.py

Prints one JSON line (the issue quotes JAX-CFD at 3.8e-2, 9.6e-3, 2.4e-3,
6.2e-4).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import mosaic
import numpy as np

sys.path.insert(0, str(Path(mosaic.__file__).parent))

from mosaic.benchmarks.core.utils import l2_error_rel  # noqa: E402
from mosaic.benchmarks.problems.navier_stokes_grid.ics import _tgv, _tgv_analytic  # noqa: E402
from tesseract_core import Tesseract  # noqa: E402

API = Path(__file__).resolve().parent / "entry" / "navier-stokes-grid" / "diffphys" / "tesseract_api.py"
NU, DT, STEPS = 0.05, 0.01, 1


def main():
    t = Tesseract.from_tesseract_api(str(API))
    errors = {}
    for n in (16, 32, 64, 128):
        ic = _tgv(n)
        out = t.apply({"v0": np.asarray(ic), "viscosity": np.array([NU], np.float32),
                       "dt": np.array([DT], np.float32), "steps": STEPS})
        ref = _tgv_analytic(ic, NU, DT * STEPS)
        errors[str(n)] = l2_error_rel(np.asarray(out["result"]), ref)
    print(json.dumps({"experiment": "forward/baseline", "solver": "diffphys",
                      "nu": NU, "dt": DT, "steps": STEPS, "l2_error_rel": errors,
                      "jax_cfd_quoted": {"16": 3.8e-2, "32": 9.6e-3, "64": 2.4e-3,
                                         "128": 6.2e-4}}))


if __name__ == "__main__":
    main()
