"""The wake reference's own error by Richardson extrapolation (docs/11).

Reads the two rollout convergence runs, D(2x, 4x) and D(4x, 8x) (each level
against the next one finer over the corrector's rollouts, restricted to the
coarse grid), and prints per Re the observed order p = log2(D(2x,4x) /
D(4x,8x)) and the estimated error of the 8x level, D(4x,8x) / (2^p - 1), for
the state's and the deviation's relative L2 error. The estimate means
something only where p is near the scheme's order (2).

    python3 benches/wake_flow/richardson.py [--json]
"""
import json
import math
import sys
from pathlib import Path

IMG = Path(__file__).resolve().parents[2] / "docs" / "img" / "wake_flow"
KEYS = {"state": "rollout_state_difference", "deviation": "rollout_deviation_difference"}


def per_re(name):
    lines = [l for l in (IMG / name).read_text().splitlines() if l.strip()]
    runs = json.loads(lines[-1])["convergence"]["per_re"]
    return {(r["split"], r["re"]): r for r in runs}


def main():
    coarse = per_re("convergence_rollout_2x4x.json")
    fine = per_re("convergence_rollout_full.json")
    rows = []
    for key in sorted(set(coarse) & set(fine), key=lambda k: k[1]):
        row = {"split": key[0], "re": key[1]}
        for metric, field in KEYS.items():
            d24, d48 = coarse[key][field], fine[key][field]
            p = math.log2(d24 / d48)
            row[metric] = {
                "d_2x_4x": d24,
                "d_4x_8x": d48,
                "order": p,
                "error_8x_estimated": d48 / (2**p - 1) if p > 0 else None,
            }
        rows.append(row)
    print("| split | Re | order (state) | 8x error, state | order (deviation) | 8x error, deviation |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for r in rows:
        s, d = r["state"], r["deviation"]
        fmt = lambda e: "n/a" if e is None else f"{e:.4f}"
        print(f"| {r['split']} | {r['re']:g} | {s['order']:.2f} | {fmt(s['error_8x_estimated'])} "
              f"| {d['order']:.2f} | {fmt(d['error_8x_estimated'])} |")
    if "--json" in sys.argv:
        print(json.dumps({"richardson": rows}))


if __name__ == "__main__":
    main()
