"""JAX and diffphys on the same CG problems, in one table and one chart.

Runs benches/anchors/jax_cg.py (skipped with a message when JAX is not
installed) and the diffphys harness on the same scene (256², 800 fixed CG
iterations, f64; and CG alone at 1024²), then prints a table of both sides'
seconds and their ratio (diffphys / JAX: below 1 means diffphys is faster) and
writes it to OUT/side_by_side.json, OUT/side_by_side.md and a bar chart
OUT/side_by_side.svg. Ends its stdout with one JSON line.

    pip install "jax[cpu]"
    python3 benches/anchors/side_by_side.py [--out out/anchors] [--repeats 5]

diffphys's figures come from one harness invocation that runs each problem
twice in a row (`--iters k,k`): the best of the two rows (results.json) is
reported, so that, as on the JAX side, the time is that of a warm run (the
first naive run faults in fresh pages for its whole tape; the second reuses
the buffers the first tape returned to diffphys_tape::pool). JAX's are medians
of --repeats runs after a warm-up that includes compilation. Both sides use
the whole machine; the script prints the load average it ran at.
"""

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))


def run_jax(repeats):
    out = subprocess.run(
        [sys.executable, os.path.join(HERE, "jax_cg.py"), "--repeats", str(repeats)],
        check=True, capture_output=True, text=True,
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def run_harness(out, args):
    subprocess.run(
        ["cargo", "run", "--release", "--quiet", "-p", "diffphys-compare", "--",
         "--precision", "f64", "--operators", "laplacian", "--out", out] + args,
        check=True, cwd=ROOT, stdout=subprocess.DEVNULL,
    )
    with open(os.path.join(out, "results.json")) as f:
        return json.load(f)


def row(rows, method, iterations):
    """The fastest (forward + backward) of the rows of `method` at `iterations`."""
    found = []
    for r in rows:
        if r["method"] == method and r.get("max_iters") == iterations and r.get("rtol") is None:
            if r.get("error"):
                raise SystemExit(f"diffphys {method} at {iterations} iterations failed: {r['error']}")
            found.append(r)
    if not found:
        raise SystemExit(f"no diffphys row for {method} at {iterations} iterations")
    return min(found, key=lambda r: r["forward_s"] + (r["backward_s"] or 0.0))


def bar_chart(path, labels, ratios):
    width, bar, gap, left = 760, 34, 22, 330
    height = 60 + len(labels) * (bar + gap)
    scale = (width - left - 40) / max(max(ratios), 1.2)
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'font-family="sans-serif" font-size="13">',
             '<text x="10" y="22" font-size="15">diffphys time / JAX time (same machine, same run; below 1: diffphys faster)</text>']
    one = left + scale
    parts.append(f'<line x1="{one:.1f}" y1="35" x2="{one:.1f}" y2="{height - 10}" stroke="#888" stroke-dasharray="4 3"/>')
    for i, (label, ratio) in enumerate(zip(labels, ratios)):
        y = 45 + i * (bar + gap)
        colour = "#2ca02c" if ratio < 1 else "#d62728"
        parts.append(f'<text x="10" y="{y + bar * 0.65:.1f}">{label}</text>')
        parts.append(f'<rect x="{left}" y="{y}" width="{ratio * scale:.1f}" height="{bar}" fill="{colour}"/>')
        parts.append(f'<text x="{left + ratio * scale + 6:.1f}" y="{y + bar * 0.65:.1f}">{ratio:.2f}</text>')
    parts.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(parts))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(ROOT, "out", "anchors"))
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)

    jax = run_jax(args.repeats)
    if "skipped" in jax:
        print("JAX is not installed: nothing to compare (pip install 'jax[cpu]')")
        print(json.dumps({"skipped": jax["skipped"]}))
        return 0
    k = jax["iterations"]
    load = os.getloadavg()
    ours256 = run_harness(os.path.join(args.out, "diffphys_256"),
                          ["--sizes", "256", "--iters", f"{k},{k}"])
    ours1024 = run_harness(os.path.join(args.out, "diffphys_1024"),
                           ["--sizes", "1024", "--iters", "200,200"])
    implicit = row(ours256, "implicit", k)
    naive = row(ours256, "naive", k)
    cg1024 = row(ours1024, "implicit", 200)

    total = lambda r: r["forward_s"] + (r["backward_s"] or 0.0)
    lines = [
        (f"implicit gradient, 256², {k} iterations", total(implicit), jax["seconds_implicit_gradient"]),
        (f"naive unrolled gradient, 256², {k} iterations", total(naive), jax["seconds_naive_gradient"]),
        ("one CG iteration, 256²", implicit["forward_s"] / k, jax["seconds_per_cg_iteration"]["256"]),
        ("one CG iteration, 1024²", cg1024["forward_s"] / 200, jax["seconds_per_cg_iteration"]["1024"]),
    ]
    table = ["| figure | diffphys (s) | JAX (s) | diffphys / JAX |", "| --- | ---: | ---: | ---: |"]
    for label, ours, theirs in lines:
        table.append(f"| {label} | {ours:.4g} | {theirs:.4g} | {ours / theirs:.2f} |")
    table.append("")
    table.append(f"Gradient errors vs exact (diffphys): implicit {implicit['grad_rel_err']:.2e}, "
                 f"naive {naive['grad_rel_err']:.2e}; JAX implicit vs naive relative difference "
                 f"{jax['gradient_rel_diff_implicit_vs_naive']:.2e}. JAX {jax['jax_version']}, "
                 f"median of {jax['repeats']} runs; diffphys best of 2 in one harness run. "
                 f"Load average before the diffphys runs: {load[0]:.2f} (1 min), {load[1]:.2f} "
                 f"(5 min) on {os.cpu_count()} cores.")
    text = "\n".join(table)
    print(text)
    with open(os.path.join(args.out, "side_by_side.md"), "w") as f:
        f.write(text + "\n")
    bar_chart(os.path.join(args.out, "side_by_side.svg"), [l for l, _, _ in lines],
              [o / t for _, o, t in lines])
    summary = {
        "ratios_diffphys_over_jax": {label: ours / theirs for label, ours, theirs in lines},
        "seconds_diffphys": {label: ours for label, ours, _ in lines},
        "seconds_jax": {label: theirs for label, _, theirs in lines},
        "jax_version": jax["jax_version"],
        "load_average": load,
    }
    with open(os.path.join(args.out, "side_by_side.json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
