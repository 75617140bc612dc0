"""Mosaic's own experiment runner (``mosaic run``) on ns-grid, with diffphys'
Tesseract and Mosaic's JAX-CFD entrant side by side, both in-process: no
Docker, no image build. Needs the diffphys package and ``pip install
mosaic-bench==0.2.0 jax-cfd==0.2.1 equinox==0.13.8`` (the last two for the
JAX-CFD entrant).

    python benches/mosaic/mosaic_run.py run -e gradient/fd_check -o /tmp/mosaic_run [--debug] [--entry DIR]
    python benches/mosaic/mosaic_run.py run -e forward/baseline  -o /tmp/mosaic_run
    python benches/mosaic/mosaic_run.py run -e cost/vjp_cost/by_N -o /tmp/mosaic_run
    python benches/mosaic/mosaic_run.py run -e optimization/drag_opt -o /tmp/mosaic_run
    python benches/mosaic/mosaic_run.py run -e gradient/fd_check_drag_opt -o /tmp/mosaic_run
    python benches/mosaic/mosaic_run.py run -e optimization/drag_opt_1000it -o /tmp/mosaic_run_1000
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
  script runs that same ``discover_solvers`` on the folder holding our entry
  (``benches/mosaic/entry/navier-stokes-grid/diffphys/``, the folder that goes
  upstream; ``--entry DIR`` takes another) and adds the ``SolverSpec`` it
  builds from the entry's ``tesseract_config.yaml`` (its ``metadata.mosaic``
  block) to the ns-grid ``Problem`` object at run time
  (``mosaic.benchmarks.problems.navier_stokes_grid.config.problem``, replaced
  by a copy with the extra solver; nothing on disk in Mosaic is touched),
  with our plot style (upstream it goes into Mosaic's ``SOLVER_STYLES``).
* The runner opens a solver in-process, without Docker, when its tag starts
  with ``inprocess:`` (``_tracked_tesseract`` in
  ``mosaic/benchmarks/core/runner.py``, documented there as a hook for
  Mosaic's own framework tests). ``mosaic run --no-build`` takes the tag
  from ``SolverSpec.image_tag`` (``image_tags_no_build``), so both solvers
  here get ``inprocess:<path to tesseract_api.py>``: the entry's, and the
  ``tesseract_api.py`` of the JAX-CFD entrant shipped inside the package.
  ``--no-build`` is therefore always passed (a build runs
  ``tesseract build``, i.e. Docker).
* The problem keeps only these two solvers (the other entrants need their
  Docker images), and JAX-CFD is marked ``uses_gpu=False`` because it runs
  on the CPU here (otherwise Mosaic's GPU auto-detection drops it on a
  machine without GPU, and its cost plots would label it "(GPU)").
* ``mosaic_shared`` (the schemas the Tesseracts import as a top-level
  package; their images copy it beside them) is put on ``sys.path``.
* Two experiments of ours are added to the registry, built from Mosaic's own
  kernels with the settings Mosaic registered (read off its registry, not
  copied; ``register_extra_experiments``): ``gradient/fd_check_drag_opt``,
  Mosaic's ``fd_check`` (its eps sweep, 20 directions, status checks) on
  ``optimization/drag_opt``'s inputs, perturbing ``inflow_profile`` with
  ``drag`` as the output, i.e. the gradient drag_opt's optimiser follows;
  and ``optimization/drag_opt_1000it``, drag_opt with 1,000 Adam iterations
  instead of 250 (outside Mosaic's budget; run it into its own ``-o``
  folder, the kernel writes its partial results under drag_opt's name).
  Both exclude the solvers Mosaic excludes from drag_opt.

``summarize`` reads Mosaic's ``result.json`` files under the output folder
and prints one JSON line with the figures (fd_check: best cosine over ε and
best median relative error over ε, Mosaic's status-check definitions, plus
every ε; forward/baseline: ``l2_error_rel`` per N; cost/vjp_cost/by_N and
by_steps: mean and trials per N or per step count; the two fd_checks alike;
optimization/drag_opt and drag_opt_1000it: initial and final drag, drag
reduction %, iterations, wall time per solver). Set
``DIFFPHYS_TESSERACT_DTYPE=float32`` to run our Tesseract in float32,
``DIFFPHYS_TESSERACT_BODY=immersed`` (or ``immersed-solid``,
``immersed-consistent``) for the immersed circle of the nominal radius
instead of the staircase, ``DIFFPHYS_TESSERACT_INFLOW=forced-column`` for
drag_opt's profile as a forced face column in the periodic box instead of
the inflow/outflow channel (see tesseract_api.py).

``gradient/fd_check_drag_opt`` runs Mosaic's ``fd_check`` in drag_opt's
unit box: Mosaic's generic kernels take the problem's domain extent (2π for
ns-grid) over the run's, so the kernel is wrapped to give it the run's
(``_in_the_runs_box``; before 2026-11-29 it ran in the 2π box).
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
# Our entry: the folder that goes upstream as
# mosaic/tesseracts/navier-stokes-grid/diffphys/ (entry/.../README.md).
ENTRY = HERE / "entry" / "navier-stokes-grid" / "diffphys"
PROBLEM = "ns-grid"
# Plot style of our solver (upstream it goes into Mosaic's SOLVER_STYLES,
# mosaic/benchmarks/problems/shared/plots/solver_styles.py; Mosaic reads no
# style from the YAML).
STYLE = {"color": "#000000", "linestyle": "-", "marker": "*"}


def load_entry(entry: Path):
    """Our solver's ``SolverSpec`` as Mosaic builds it for an entrant:
    Mosaic's own ``discover_solvers`` on the folder holding ``entry``, which
    reads ``entry/tesseract_config.yaml``'s ``metadata.mosaic`` block (name,
    backend, scheme, AD strategy, dtype...) and its top-level description.
    Raises ValueError, naming the folder, if ``entry`` is not an entry."""
    from mosaic.benchmarks.core.config import discover_solvers

    entry = Path(entry).resolve()
    for f in ("tesseract_api.py", "tesseract_config.yaml"):
        if not (entry / f).is_file():
            raise ValueError(f"--entry {entry}: no {f} in it (a Mosaic entry holds "
                             "tesseract_api.py and tesseract_config.yaml)")
    found = {s.dir: s for s in discover_solvers(entry.parent).values()}
    if entry.name not in found:
        raise ValueError(f"--entry {entry}: Mosaic's discover_solvers does not take it "
                         "(its tesseract_config.yaml needs a metadata.mosaic block with a name)")
    return found[entry.name]


def register_inprocess_solvers(entry: Path = ENTRY) -> None:
    """Give ns-grid's Problem the two in-process solvers (see module docs):
    ours as Mosaic discovers it from ``entry`` (``load_entry``), run from
    ``entry/tesseract_api.py``."""
    from mosaic.benchmarks.problems.navier_stokes_grid import config as ns

    prob = ns.problem
    jax_cfd = prob.solver("jax-cfd")
    jax_cfd = dataclasses.replace(
        jax_cfd,
        image_tag="inprocess:" + str(prob.tesseract_dir / jax_cfd.dir / "tesseract_api.py"),
        uses_gpu=False,
    )
    spec = load_entry(entry)
    dtype = os.environ.get("DIFFPHYS_TESSERACT_DTYPE")
    diffphys = dataclasses.replace(
        spec,
        **STYLE,
        **({"internal_dtype": dtype} if dtype else {}),
        image_tag="inprocess:" + str(Path(entry).resolve() / "tesseract_api.py"),
    )
    # dataclasses.replace re-runs Problem.__post_init__, which rebuilds the
    # name -> spec table make_inputs looks solvers up in.
    ns.problem = dataclasses.replace(prob, solvers=[jax_cfd, diffphys])


def _registered(prob, key: str) -> tuple[dict, list]:
    """The run dict (its ``ic``, ``physics``, ``fd``/``optim``...) and the
    status checks Mosaic registered for experiment ``key``: read off the
    registered closure (``Problem.add_experiment`` keeps the config only
    there), so the added experiments below take Mosaic's own settings."""
    import inspect

    exp = prob.experiments[key]
    kw = inspect.signature(exp.fn).parameters["_kw"].default
    (run,) = kw["runs"]
    return run, list(exp.params.get("status_check", []))


def _in_the_runs_box(kernel):
    """``kernel`` on the domain extent of the run's own physics.

    Mosaic's generic kernels get ``ctx.phys`` with the problem's
    ``domain_extent`` (2π for ns-grid) written over the run's
    (``experiment.py``: ``phys = {**base_phys, "domain_extent":
    domain_extent}``); drag_opt's own kernel reads the run's physics (1.0).
    Without this, fd_check on drag_opt's inputs runs in a 2π box, where the
    cylinder of radius 0.05 is a fifth of a cell wide (one solid cell on the
    staircase). The wrapper keeps the kernel's Mosaic configuration."""
    import functools

    from mosaic.benchmarks.core.experiment import _KERNEL_CONFIG_ATTR

    @functools.wraps(kernel)
    def wrapped(t, ctx):
        de = ctx.run.get("physics", {}).get("domain_extent", ctx.domain_extent)
        ctx = dataclasses.replace(ctx, phys={**ctx.phys, "domain_extent": de}, domain_extent=de)
        return kernel(t, ctx)

    setattr(wrapped, _KERNEL_CONFIG_ATTR, getattr(kernel, _KERNEL_CONFIG_ATTR))
    return wrapped


def register_extra_experiments() -> None:
    """Two experiments Mosaic 0.2.0 does not have, both ours, built from its
    own kernels and settings (see the module docs):

    * ``gradient/fd_check_drag_opt``: Mosaic's ``fd_check`` kernel, eps
      sweep, directions and status checks (``gradient/fd_check``'s), on
      ``optimization/drag_opt``'s inputs (its ``flat_inflow`` profile and
      physics), perturbing ``inflow_profile`` and checking the gradient of
      ``drag**2``: the gradient drag_opt's Adam steps follow.
    * ``optimization/drag_opt_1000it``: ``optimization/drag_opt`` with
      ``max_iters`` 1,000 instead of 250, everything else Mosaic's:
      outside Mosaic's budget. Run it into its own output folder (``-o``):
      the kernel writes its partial results under ``drag_opt``'s name.
    """
    from mosaic.benchmarks.problems.navier_stokes_grid import config as ns
    from mosaic.benchmarks.problems.navier_stokes_grid.exclusions import _OBSTACLE_GATE
    from mosaic.benchmarks.problems.navier_stokes_grid.optimization import drag_opt
    from mosaic.benchmarks.problems.shared.gradient import fd_check

    prob = ns.problem
    drag, _ = _registered(prob, "optimization/drag_opt")
    fd, fd_checks = _registered(prob, "gradient/fd_check")
    prob.add_experiment(
        "gradient/fd_check_drag_opt", _in_the_runs_box(fd_check),
        plot_description="diffphys' addition: fd_check on drag_opt's inflow profile and drag.",
        status_check=fd_checks,
        ic=drag["ic"], physics=drag["physics"], fd=fd["fd"],
        ic_key="inflow_profile", output_key="drag",
    )
    prob.exclude("gradient/fd_check_drag_opt", _OBSTACLE_GATE)
    prob.add_experiment(
        "optimization/drag_opt_1000it", drag_opt,
        plot_description="diffphys' addition: drag_opt with 1,000 Adam iterations "
                         "(outside Mosaic's budget of 250).",
        ic=drag["ic"], physics=drag["physics"], optim={**drag["optim"], "max_iters": 1000},
    )
    prob.exclude("optimization/drag_opt_1000it", _OBSTACLE_GATE)


def run_mosaic_cli(argv: list[str]) -> None:
    entry = ENTRY
    if "--entry" in argv:
        i = argv.index("--entry")
        if i + 1 >= len(argv):
            raise SystemExit("--entry needs a folder (holding tesseract_api.py and "
                             "tesseract_config.yaml)")
        entry = Path(argv[i + 1])
        argv = argv[:i] + argv[i + 2:]
    try:
        register_inprocess_solvers(entry)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    register_extra_experiments()
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


def _summarize_fd(out: dict, base: Path, exp: str, sfx: str) -> None:
    fd = _load(base / "gradient" / f"{exp}{sfx}" / "result.json")
    if fd is None:
        return
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
    out[f"gradient/{exp}"] = {
        "file": str(base / "gradient" / f"{exp}{sfx}" / "result.json"),
        "params": fd.get("params", {}).get("physics"),
        "n_dirs": fd.get("params", {}).get("fd", {}).get("n_dirs"),
        "thresholds": {"min_cosine": 0.99, "max_rel_err": 1e-3},
        "by_solver": rows,
        "solver_failures": fd.get("_solver_failures"),
    }


def summarize(root: Path, debug: bool) -> dict:
    sfx = "_debug" if debug else ""
    base = root / PROBLEM
    out: dict = {"results_dir": str(root), "debug": debug}

    for exp in ("fd_check", "fd_check_drag_opt"):
        _summarize_fd(out, base, exp, sfx)

    for exp in ("drag_opt", "drag_opt_1000it"):
        path = base / "optimization" / f"{exp}{sfx}" / "result.json"
        do = _load(path)
        if do is None:
            continue
        rows = {}
        for entry in do["results"]:
            m = entry.get("metrics") or {}
            rows[entry["solver"]] = {
                k: m.get(k) for k in ("initial_drag", "final_drag", "drag_reduction_pct",
                                      "n_iters", "converged", "error")
                if m.get(k) is not None}
            if m.get("drags"):
                rows[entry["solver"]]["min_abs_drag"] = min(abs(x) for x in m["drags"])
            if m.get("flow_rates"):
                rows[entry["solver"]]["final_flow_rate"] = m["flow_rates"][-1]
        prov = do.get("provenance", {})
        out[f"optimization/{exp}"] = {
            "file": str(path),
            "params": do.get("params"),
            "by_solver": rows,
            "wall_time_s": prov.get("wall_time_s"),
            "timestamp": prov.get("run_meta", {}).get("timestamp"),
            "platform": prov.get("environment", {}).get("platform"),
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
    # every other experiment: its scalar metrics per solver and sweep value
    # (for an eps sweep, the best cosine and relative error over eps)
    done = {k for k in out if "/" in k}
    for path in sorted(base.glob(f"*/**/result.json")):
        rel = path.parent.relative_to(base).as_posix()
        if sfx and not rel.endswith(sfx):
            continue
        key = rel[: len(rel) - len(sfx)] if sfx else rel
        if key in done or (not sfx and rel.endswith("_debug")):
            continue
        res = _load(path)
        if not res or "results" not in res:
            continue
        rows: dict = {}
        for entry in res["results"]:
            m = entry.get("metrics") or {}
            row = {k: v for k, v in m.items() if isinstance(v, (int, float, str, bool))}
            sweep = m.get("eps_sweep")
            if isinstance(sweep, dict) and sweep:
                cos = [v.get("cosine_mean", v.get("cosine")) for v in sweep.values()]
                err = [v.get("rel_error_mean") if "rel_error_mean" in v
                       else statistics.median(v["rel_error"]) for v in sweep.values()
                       if "rel_error_mean" in v or "rel_error" in v]
                row["best_cosine"] = max(c for c in cos if c is not None)
                row["best_rel_error"] = min(err) if err else None
            sv = entry.get("sweep_value")
            rows.setdefault(entry["solver"], {})[str(sv)] = row
        out[key] = {
            "file": str(path),
            "params": res.get("params"),
            "sweep": res.get("sweep"),
            "by_solver": rows,
            "solver_failures": res.get("_solver_failures"),
            "timestamp": res.get("provenance", {}).get("run_meta", {}).get("timestamp"),
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
