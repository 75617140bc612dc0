"""Stage our Mosaic entry into a checkout of Mosaic, as the upstream pull
request would add it, and run the checks Mosaic offers for a solver folder.

    git clone --branch v0.2.0 https://github.com/pasteurlabs/mosaic /tmp/mosaic-src
    python benches/mosaic/entry/stage.py --mosaic-repo /tmp/mosaic-src [--build]

What it does, in the checkout (nothing else is written):

1. copies the entry's three files (``navier-stokes-grid/diffphys/``:
   tesseract_api.py, tesseract_config.yaml, tesseract_requirements.txt) to
   ``mosaic/tesseracts/navier-stokes-grid/diffphys/``;
2. writes diffphys' source distribution beside them
   (``maturin sdist -m crates/python/Cargo.toml``: the Rust workspace crates
   it needs included), which tesseract_requirements.txt installs;
3. adds our plot style to Mosaic's ``SOLVER_STYLES``
   (``mosaic/benchmarks/problems/shared/plots/solver_styles.py``), where
   Mosaic keeps styles (not in the YAML);
4. runs Mosaic's checks: its CI config validator
   (``.github/scripts/validate-tesseract-configs.py``), its solver discovery
   (``get_config("ns-grid")`` with the checkout first on ``PYTHONPATH``: our
   SolverSpec as Mosaic builds it), its tests on problem configs and the
   solver reference page (``tests/test_problem_configs.py``,
   ``tests/test_docs_generate.py``), and tesseract-core's own parse of the
   config with the build context and Dockerfile rendered (what
   ``tesseract build --generate-only`` does, called through tesseract-core's
   Python API because its CLI first insists on a Docker daemon);
5. with ``--build``, if ``docker info`` answers: ``tesseract build`` of the
   folder (the image ``diffphys_navier_stokes_grid``).

Ends its stdout with one JSON line of what passed. Needs mosaic-bench (its
test dependencies: pytest, pyyaml), tesseract-core and maturin in the running
Python's environment.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ENTRY = HERE / "navier-stokes-grid" / "diffphys"
REPO = HERE.parents[2]
FILES = ("tesseract_api.py", "tesseract_config.yaml", "tesseract_requirements.txt")
SOLVER = "diffphys"
STYLE_LINE = '    "diffphys": {"color": "#000000", "linestyle": "-", "marker": "*"},\n'


def _tool(name: str) -> str:
    """An executable of the running environment (beside sys.executable), else PATH."""
    cand = Path(sys.executable).parent / name
    if cand.exists():
        return str(cand)
    found = shutil.which(name)
    if not found:
        raise SystemExit(f"stage.py: {name} not found (install it in this Python's environment)")
    return found


def _run(cmd: list[str], cwd: Path, env: dict | None = None, timeout: float = 1800) -> dict:
    print("$", " ".join(cmd), flush=True)
    p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    tail = (p.stdout + p.stderr).strip().splitlines()[-15:]
    print("\n".join(tail), flush=True)
    return {"rc": p.returncode, "tail": tail[-3:]}


def stage(clone: Path) -> Path:
    dest = clone / "mosaic" / "tesseracts" / "navier-stokes-grid" / SOLVER
    dest.mkdir(parents=True, exist_ok=True)
    for f in FILES:
        shutil.copy2(ENTRY / f, dest / f)
    styles = clone / "mosaic" / "benchmarks" / "problems" / "shared" / "plots" / "solver_styles.py"
    text = styles.read_text()
    if f'"{SOLVER}":' not in text:
        anchor = '    "jax_cfd":'
        if anchor not in text:
            raise SystemExit(f"stage.py: {styles} has no {anchor!r} line to add our style after")
        i = text.index("\n", text.index(anchor)) + 1
        styles.write_text(text[:i] + STYLE_LINE + text[i:])
    return dest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mosaic-repo", type=Path, required=True,
                    help="a checkout of pasteurlabs/mosaic (v0.2.0)")
    ap.add_argument("--no-sdist", action="store_true",
                    help="skip `maturin sdist` (keep a diffphys-*.tar.gz already staged)")
    ap.add_argument("--build", action="store_true",
                    help="also `tesseract build` the staged folder (needs a Docker daemon)")
    a = ap.parse_args()
    clone = a.mosaic_repo.resolve()
    if not (clone / "mosaic" / "tesseracts" / "navier-stokes-grid").is_dir():
        raise SystemExit(f"stage.py: {clone} is not a Mosaic checkout "
                         "(no mosaic/tesseracts/navier-stokes-grid)")
    out: dict = {"mosaic_repo": str(clone)}
    dest = stage(clone)
    out["staged"] = str(dest)

    if not a.no_sdist:
        for old in dest.glob("diffphys-*.tar.gz"):
            old.unlink()
        r = _run([_tool("maturin"), "sdist", "-m", str(REPO / "crates" / "python" / "Cargo.toml"),
                  "-o", str(dest)], cwd=REPO)
        out["sdist"] = {"rc": r["rc"], "files": sorted(p.name for p in dest.glob("diffphys-*.tar.gz"))}
    wanted = [ln.strip() for ln in (dest / "tesseract_requirements.txt").read_text().splitlines()
              if ln.strip().startswith("./diffphys-")]
    missing = [w for w in wanted if not (dest / w).exists()]
    if missing:
        raise SystemExit(f"stage.py: tesseract_requirements.txt names {missing}, not in {dest} "
                         "(run without --no-sdist, or bump the version in the requirements)")

    env = {**os.environ, "PYTHONPATH": str(clone) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    py = sys.executable
    out["validate_tesseract_configs"] = _run(
        [py, ".github/scripts/validate-tesseract-configs.py"], cwd=clone)
    probe = (
        "import json, mosaic\n"
        "from mosaic.benchmarks.problems import get_config\n"
        f"s = get_config('ns-grid').solver({SOLVER!r})\n"
        "print(json.dumps({'mosaic_from': mosaic.__file__, 'name': s.name, 'dir': s.dir,\n"
        "  'backend': s.backend, 'scheme': s.scheme, 'ad_strategy': str(s.ad_strategy),\n"
        "  'differentiable': s.differentiable, 'uses_gpu': s.uses_gpu,\n"
        "  'internal_dtype': s.internal_dtype, 'image_tag': s.image_tag, 'color': s.color}))\n"
    )
    r = _run([py, "-c", probe], cwd=clone, env=env)
    out["discover"] = {"rc": r["rc"], **(json.loads(r["tail"][-1]) if r["rc"] == 0 else {})}
    out["mosaic_tests"] = _run(
        [py, "-m", "pytest", "-q", "-p", "no:cacheprovider",
         "tests/test_problem_configs.py", "tests/test_docs_generate.py"], cwd=clone, env=env)

    build_dir = clone / ".tesseract-build-diffphys"
    if build_dir.exists():
        shutil.rmtree(build_dir)
    build_dir.mkdir()
    # `tesseract build --generate-only` without its Docker-daemon check (the
    # CLI refuses to start without a daemon): the same three calls
    # build_tesseract makes before handing the context to Docker.
    gen = (
        "import sys\n"
        "from tesseract_core.sdk import engine\n"
        "src = engine.Path(sys.argv[1])\n"
        "engine.validate_tesseract_api(src)\n"
        "cfg = engine.get_config(src)\n"
        "ctx = engine.prepare_build_context(src, engine.Path(sys.argv[2]), cfg)\n"
        "print(cfg.name, cfg.build_config.base_image, ctx)\n"
    )
    r = _run([py, "-c", gen, str(dest), str(build_dir)], cwd=clone)
    docker_file = build_dir / "Dockerfile"
    staged_reqs = sorted(p.name for p in (build_dir / "local_requirements").glob("*")) \
        if (build_dir / "local_requirements").is_dir() else []
    out["generate_only"] = {"rc": r["rc"], "dockerfile": docker_file.exists(),
                            "local_requirements": staged_reqs}

    d = subprocess.run(["docker", "info"], capture_output=True, text=True) \
        if shutil.which("docker") else None
    out["docker"] = "no docker client" if d is None else (
        "daemon answers" if d.returncode == 0 else "client only: " + (
            [ln for ln in d.stderr.splitlines() if ln.strip()] or ["docker info failed"])[-1].strip())
    if a.build:
        if d is not None and d.returncode == 0:
            out["build"] = _run([_tool("tesseract"), "build", str(dest)], cwd=clone, timeout=7200)
        else:
            out["build"] = "not run: " + out["docker"]
    out["ok"] = all(out[k]["rc"] == 0 for k in
                    ("validate_tesseract_configs", "discover", "mosaic_tests", "generate_only")) \
        and out.get("sdist", {"rc": 0})["rc"] == 0
    print(json.dumps(out))


if __name__ == "__main__":
    main()
