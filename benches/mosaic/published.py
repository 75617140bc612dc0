"""The published ns-grid figures of Mosaic's entrants, read from Mosaic's
``benchmark-results`` branch (``main/ns-grid/<suite>/<experiment>/result.json``),
in the shape ``mosaic_run.py summarize`` gives ours, for the tables of
docs/results/mosaic.md.

    python benches/mosaic/published.py --repo PATH_TO_MOSAIC_GIT [--ref benchmark-results] [--out FILE]
    python benches/mosaic/published.py --dir PATH_TO_CHECKED_OUT_RESULTS   # the folder holding main/

(A clone of github.com/pasteurlabs/mosaic has the branch.) Per experiment
and solver: forward errors (``error`` or ``analytic_error``, divergence and
kinetic energy) per sweep value; gradient checks per sweep value (gradient
norm, best cosine and best mean relative error over eps); the Jacobian SVD's
condition number and effective rank per solver; cost means per N or step
count with the hardware the file names; drag_opt's drags, reduction,
iterations and wall time. Prints one JSON line (and writes it to ``--out``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
from pathlib import Path

EXPERIMENTS = [
    "forward/baseline", "forward/agreement/tgv", "forward/agreement/multimode",
    "forward/tgv_nu_sweep", "forward/physical_laws/vs_N", "forward/physical_laws/vs_steps",
    "forward/physical_laws/vs_nu", "forward/cylinder", "cost/spatial_cost",
    "cost/temporal_cost", "cost/vjp_cost/by_N", "cost/vjp_cost/by_steps", "gradient/fd_check",
    "gradient/param_sweep", "gradient/horizon_sweep", "gradient/jacobian_svd",
    "gradient/jacobian_svd_steps20", "gradient/jacobian_svd_steps40",
    "gradient/jacobian_svd_nu01", "optimization/drag_opt",
]


def _reader(args):
    if args.dir:
        root = Path(args.dir)

        def read(rel: str):
            p = root / rel
            return json.loads(p.read_text()) if p.exists() else None
        return read, str(root)

    def read(rel: str):
        r = subprocess.run(["git", "-C", args.repo, "show", f"{args.ref}:{rel}"],
                           capture_output=True, text=True)
        return json.loads(r.stdout) if r.returncode == 0 else None
    sha = subprocess.run(["git", "-C", args.repo, "rev-parse", args.ref],
                         capture_output=True, text=True).stdout.strip()
    return read, f"{args.repo}@{args.ref} ({sha})"


def _eps_best(sweep: dict) -> dict:
    """Best over eps: the cosine, and the relative error (the mean over the
    directions in param/horizon sweeps, the median in fd_check, Mosaic's
    status-check definitions)."""
    cos, err = [], []
    for v in sweep.values():
        cos.append(v.get("cosine_mean", v.get("cosine")))
        if v.get("rel_error_mean") is not None:
            err.append(v["rel_error_mean"])
        elif isinstance(v.get("rel_error"), list) and v["rel_error"]:
            err.append(statistics.median(v["rel_error"]))
    return {"best_cosine": max((c for c in cos if c is not None), default=None),
            "best_rel_error": min((e for e in err if e is not None), default=None)}


def _scalars(m: dict) -> dict:
    return {k: v for k, v in m.items() if isinstance(v, (int, float, str, bool))}


def extract(key: str, d: dict) -> dict:
    out: dict = {"params": d.get("params"), "wall_time_s": d.get("wall_time_s")}
    if "hardware" in d:
        out["hardware"] = d["hardware"]
    if "reference_label" in d:
        out["reference_label"] = d["reference_label"]
    rows: dict = {}
    if "by_param" in d:  # forward: {value: {solver: metrics}}
        for value, per in d["by_param"].items():
            for solver, m in per.items():
                rows.setdefault(solver, {})[value] = _scalars(m)
    elif key.startswith("gradient/jacobian_svd"):
        for solver in d.get("solver_names", []):
            rows[solver] = {"cond": d.get("per_solver_cond", {}).get(solver),
                            "eff_rank": d.get("per_solver_eff_rank", {}).get(solver),
                            "grad_norm": d.get("per_solver_grad_norm", {}).get(solver)}
    elif key == "optimization/drag_opt":
        for solver, m in d["by_solver"].items():
            rows[solver] = {k: m.get(k) for k in ("initial_drag", "final_drag",
                                                  "drag_reduction_pct", "n_iters", "converged")}
    elif "by_solver" in d:  # gradient: {solver: {value: metrics}} or {solver: metrics}
        for solver, per in d["by_solver"].items():
            if "eps_sweep" in per:
                per = {"None": per}
            for value, m in per.items():
                row = _scalars(m)
                if isinstance(m.get("eps_sweep"), dict):
                    row.update(_eps_best(m["eps_sweep"]))
                rows.setdefault(solver, {})[value] = row
    else:  # cost: {"by_N"|"by_steps": {solver: {value: metrics}}}
        for k in ("by_N", "by_steps"):
            for solver, per in (d.get(k) or {}).items():
                for value, m in per.items():
                    rows.setdefault(solver, {})[value] = {
                        x: m.get(x) for x in ("mean", "std", "status") if m.get(x) is not None}
    out["by_solver"] = rows
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--repo", help="a git clone of pasteurlabs/mosaic")
    src.add_argument("--dir", help="a folder holding the branch's main/")
    ap.add_argument("--ref", default="benchmark-results")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    read, source = _reader(args)
    out: dict = {"source": source, "missing": []}
    for key in EXPERIMENTS:
        d = read(f"main/ns-grid/{key}/result.json")
        if d is None:
            out["missing"].append(key)
            continue
        out[key] = extract(key, d)
    s = json.dumps(out)
    if args.out:
        args.out.write_text(s + "\n")
    print(s)


if __name__ == "__main__":
    main()
