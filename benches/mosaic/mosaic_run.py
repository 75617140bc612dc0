"""Mosaic's own experiment runner (``mosaic run``) on ns-grid, with diffphys'
Tesseract and Mosaic's JAX-CFD entrant side by side, both in-process: no
Docker, no image build.

    python benches/mosaic/mosaic_run.py run -e gradient/fd_check -o /tmp/mosaic_run [--debug]
    python benches/mosaic/mosaic_run.py run -e forward/baseline  -o /tmp/mosaic_run
    python benches/mosaic/mosaic_run.py run -e cost/vjp_cost/by_N -o /tmp/mosaic_run
    python benches/mosaic/mosaic_run.py status -p ns-grid -o /tmp/mosaic_run
    python benches/mosaic/mosaic_run.py summarize /tmp/mosaic_run [--debug] [--out FILE]

Every subcommand except ``summarize`` is Mosaic's own Typer CLI
(``mosaic.benchmarks.cli:app``, the ``mosaic`` console script), unchanged:
its experiment registry, input factory, harnesses (``fd_check``,
``agreement``, ``vjp_cost``), timing, status checks and result files. This
script only adds what Mosaic 0.2.0 has no public hook for, before the CLI
starts:

* Mosaic finds a problem's solvers by scanning the ``tesseracts/<slug>/``
  folder inside its installed package (``discover_solvers`` in
  ``mosaic/benchmarks/core/config.py``) and gives each the Docker tag
  ``<name>:latest``. There is no config file, entry point, environment
  variable or registration call that adds a solver from elsewhere, so this
  script adds a ``SolverSpec`` for diffphys to the ns-grid ``Problem``
  object at run time (``mosaic.benchmarks.problems.navier_stokes_grid.config
  .problem``, replaced by a copy with the extra solver; nothing on disk in
  Mosaic is touched).
* The runner opens a solver in-process, without Docker, when its tag starts
  with ``inprocess:`` (``_tracked_tesseract`` in
  ``mosaic/benchmarks/core/runner.py``, documented there as a hook for
  Mosaic's own framework tests). ``mosaic run --no-build`` takes the tag
  from ``SolverSpec.image_tag`` (``image_tags_no_build``), so both solvers
  here get ``inprocess:<path to tesseract_api.py>``: ours, and the
  ``tesseract_api.py`` of the JAX-CFD entrant shipped inside the package.
  ``--no-build`` is therefore always passed (a build runs
  ``tesseract build``, i.e. Docker).
* The problem keeps only these two solvers (the other entrants need their
  Docker images), and JAX-CFD is marked ``uses_gpu=False`` because it runs
  on the CPU here (otherwise Mosaic's GPU auto-detection drops it on a
  machine without GPU, and its cost plots would label it "(GPU)").
* ``mosaic_shared`` (the schemas the Tesseracts import as a top-level
  package; their images copy it beside them) is put on ``sys.path``.

``summarize`` reads Mosaic's ``result.json`` files under the output folder
and prints one JSON line with the figures (fd_check: best cosine over ε and
best median relative error over ε, Mosaic's status-check definitions, plus
every ε; forward/baseline: ``l2_error_rel`` per N; cost/vjp_cost/by_N and
by_steps: mean and trials per N or per step count). Set
``DIFFPHYS_TESSERACT_DTYPE=float32`` to run our Tesseract in float32 (see
tesseract_api.py).
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import sys
from pathlib import Path

import mosaic

MOSAIC_DIR = Path(mosaic.__file__).resolve().parent
# mosaic_shared as a top-level package, for both Tesseracts
sys.path.insert(0, str(MOSAIC_DIR))

HERE = Path(__file__).resolve().parent
OURS = HERE / "tesseract_api.py"
PROBLEM = "ns-grid"


def register_inprocess_solvers() -> None:
    """Give ns-grid's Problem the two in-process solvers (see module docs)."""
    from mosaic.benchmarks.core.config import AdStrategy, SolverSpec
    from mosaic.benchmarks.problems.navier_stokes_grid import config as ns

    prob = ns.problem
    jax_cfd = prob.solver("jax-cfd")
    jax_cfd = dataclasses.replace(
        jax_cfd,
        image_tag="inprocess:" + str(prob.tesseract_dir / jax_cfd.dir / "tesseract_api.py"),
        uses_gpu=False,
    )
    diffphys = SolverSpec(
        dir="diffphys",
        name="diffphys",
        color="#000000",
        linestyle="-",
        marker="*",
        scheme="MAC FD + projection",
        backend="rust",
        family="projection",
        description=(
            "diffphys' flow step (Rust): MAC grid, semi-Lagrangian advection, FFT "
            "pressure projection on the periodic box; hand-written adjoints over a "
            "recorded tape."
        ),
        doc_url="",
        differentiable=True,
        ad_strategy=AdStrategy.ADJOINT,
        uses_gpu=False,
        internal_dtype=os.environ.get("DIFFPHYS_TESSERACT_DTYPE", "float64"),
        image_tag="inprocess:" + str(OURS),
    )
    # dataclasses.replace re-runs Problem.__post_init__, which rebuilds the
    # name -> spec table make_inputs looks solvers up in.
    ns.problem = dataclasses.replace(prob, solvers=[jax_cfd, diffphys])


def run_mosaic_cli(argv: list[str]) -> None:
    register_inprocess_solvers()
    if argv and argv[0] == "run":
        if "--no-build" not in argv:
            argv = [*argv, "--no-build"]
        if not any(a in ("-p", "--problems") or a.startswith("--problems=") for a in argv):
            argv = [*argv, "-p", PROBLEM]
    from mosaic.benchmarks.cli import app

    app(args=argv, prog_name="mosaic")


# ── summarize ────────────────────────────────────────────────────────────────


def _load(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        return None


def summarize(root: Path, debug: bool) -> dict:
    sfx = "_debug" if debug else ""
    base = root / PROBLEM
    out: dict = {"results_dir": str(root), "debug": debug}

    fd = _load(base / "gradient" / f"fd_check{sfx}" / "result.json")
    if fd is not None:
        rows = {}
        for entry in fd["results"]:
            m = entry.get("metrics") or {}
            sweep = m.get("eps_sweep") or {}
            per_eps = {
                str(eps): {"cosine": st["cosine"],
                           "median_rel_error": statistics.median(st["rel_error"])}
                for eps, st in sweep.items()
            }
            rows[entry["solver"]] = {
                "best_cosine": max((v["cosine"] for v in per_eps.values()), default=None),
                "best_median_rel_error": min(
                    (v["median_rel_error"] for v in per_eps.values()), default=None),
                "per_eps": per_eps,
            }
        out["gradient/fd_check"] = {
            "file": str(base / "gradient" / f"fd_check{sfx}" / "result.json"),
            "params": fd.get("params", {}).get("physics"),
            "n_dirs": fd.get("params", {}).get("fd", {}).get("n_dirs"),
            "thresholds": {"min_cosine": 0.99, "max_rel_err": 1e-3},
            "by_solver": rows,
            "solver_failures": fd.get("_solver_failures"),
        }

    bl = _load(base / "forward" / f"baseline{sfx}" / "result.json")
    if bl is not None:
        rows: dict = {}
        for entry in bl["results"]:
            m = entry.get("metrics") or {}
            rows.setdefault(entry["solver"], {})[entry["sweep_value"]] = m.get("error")
        out["forward/baseline"] = {
            "file": str(base / "forward" / f"baseline{sfx}" / "result.json"),
            "params": bl.get("params", {}).get("physics"),
            "sweep": bl.get("sweep"),
            "reference_label": bl.get("extras", {}).get("reference_label"),
            "l2_error_rel": rows,
            "solver_failures": bl.get("_solver_failures"),
        }

    for variant in ("by_N", "by_steps"):
        path = base / "cost" / f"vjp_cost/{variant}{sfx}" / "result.json"
        vc = _load(path)
        if vc is None:
            continue
        rows = {}
        for entry in vc["results"]:
            m = entry.get("metrics") or {}
            rows.setdefault(entry["solver"], {})[entry["sweep_value"]] = {
                k: m.get(k) for k in ("mean", "std", "trials_s", "grad_norm", "status",
                                      "failure_type", "exc_msg")
                if m.get(k) is not None
            }
        out[f"cost/vjp_cost/{variant}"] = {
            "file": str(path),
            "params": vc.get("params", {}).get("physics"),
            "cost": vc.get("params", {}).get("cost"),
            "sweep": vc.get("sweep"),
            "by_solver": rows,
            "hardware": vc.get("extras", {}).get("hardware"),
            "timestamp": vc.get("provenance", {}).get("run_meta", {}).get("timestamp"),
        }
    return out


def main() -> None:
    argv = sys.argv[1:]
    if argv and argv[0] == "summarize":
        import argparse

        ap = argparse.ArgumentParser(prog="mosaic_run.py summarize")
        ap.add_argument("root", type=Path)
        ap.add_argument("--debug", action="store_true")
        ap.add_argument("--out", type=Path)
        a = ap.parse_args(argv[1:])
        s = json.dumps(summarize(a.root, a.debug))
        if a.out:
            a.out.parent.mkdir(parents=True, exist_ok=True)
            a.out.write_text(s + "\n")
        print(s)
        return
    run_mosaic_cli(argv)


if __name__ == "__main__":
    main()
