"""The flow step beside its peers: PhiFlow 3.4 and JAX-CFD 0.2.1 against diffphys-flow, one core each.

Makes a venv of its own (default target/flow_peers/venv), pip-installs the pinned
peers of requirements.txt into it, builds our worker (the `flow_step` example,
release), then for each setting starts the peer's worker and ours as separate
processes pinned to one core (taskset; XLA single-threaded; RAYON_NUM_THREADS=1)
and interleaves their timed repetitions: peer fwd, peer fwd+bwd, ours fwd, ours
fwd+bwd, and again, --repeats times. Prints per-step times (best, median,
worst), the backward/forward ratio, the peak resident memory of each process
(from wait4), the ratio ours / peer (best of each, and the median and range of
the paired repetitions), and ends with one JSON line (also written to
OUT/flow_peers.json).

Settings (the flow-step issue's): PhiFlow's wake-flow step (the PBDL book's,
f32, CG to 1e-3) at 32 x 64 and 128 x 256, rollout of 20 steps; JAX-CFD's
periodic Taylor-Green box at 128^2 in f32 and f64, rollout of 100 steps, and at 512^2
in f32, rollout of 20 steps.

    python3 benches/flow_peers/run.py                  # everything
    python3 benches/flow_peers/run.py --peers-only     # the peers alone
    python3 benches/flow_peers/run.py --only wake32,box128_f32 --repeats 9
    python3 benches/flow_peers/run.py --only box128_f32,box512_f32 --python /path/to/venv/bin/python

Nothing in the Rust build or its tests depends on this script.
"""

import argparse
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
# our worker, where cargo puts it (CARGO_TARGET_DIR if set)
OURS = os.path.join(os.environ.get("CARGO_TARGET_DIR") or os.path.join(ROOT, "target"),
                    "release", "examples", "flow_step")

# name: (peer worker and its arguments, our worker's arguments, floor on ours/peer fwd+bwd)
SETTINGS = {
    "wake32": (["phiflow_worker.py", "--res", "32", "--steps", "20"],
               ["--scene", "wake", "--res", "32", "--steps", "20"], 0.25),
    "wake128": (["phiflow_worker.py", "--res", "128", "--steps", "20"],
                ["--scene", "wake", "--res", "128", "--steps", "20"], 0.25),
    "box128_f32": (["jaxcfd_worker.py", "--n", "128", "--steps", "100"],
                   ["--scene", "box", "--res", "128", "--steps", "100"], 1.0),
    "box128_f64": (["jaxcfd_worker.py", "--n", "128", "--steps", "100", "--f64"],
                   ["--scene", "box", "--res", "128", "--steps", "100", "--f64"], 1.0),
    "box512_f32": (["jaxcfd_worker.py", "--n", "512", "--steps", "20"],
                   ["--scene", "box", "--res", "512", "--steps", "20"], 1.0),
}


def venv_python(venv):
    """The venv's python, made and filled from requirements.txt when missing or stale."""
    python = os.path.join(venv, "bin", "python")
    requirements = os.path.join(HERE, "requirements.txt")
    with open(requirements, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()
    stamp = os.path.join(venv, "requirements.sha256")
    if os.path.exists(stamp) and open(stamp).read().strip() == digest and os.path.exists(python):
        return python
    print(f"making the peers' venv at {venv} (pip install -r {os.path.relpath(requirements, ROOT)})", flush=True)
    shutil.rmtree(venv, ignore_errors=True)
    subprocess.run([sys.executable, "-m", "venv", venv], check=True)
    subprocess.run([python, "-m", "pip", "install", "--quiet", "--upgrade", "pip"], check=True)
    subprocess.run([python, "-m", "pip", "install", "--quiet", "-r", requirements], check=True)
    with open(stamp, "w") as f:
        f.write(digest + "\n")
    return python


class Worker:
    """One benchmark process speaking worker_protocol.md."""

    def __init__(self, label, argv, env, core):
        self.label = label
        pinned = ["taskset", "-c", str(core)] + argv if shutil.which("taskset") else argv
        self.proc = subprocess.Popen(pinned, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     env=env, cwd=ROOT, bufsize=1)
        self.times = {"fwd": [], "fwdbwd": []}
        self.cpu = {"fwd": [], "fwdbwd": []}
        self.info = self.read()
        if not self.info.get("ready"):
            raise SystemExit(f"{label}: worker did not get ready: {self.info}")

    def read(self):
        while True:
            line = self.proc.stdout.readline()
            if not line:
                code = self.proc.wait()
                raise SystemExit(f"{self.label}: worker exited with {code} before answering")
            if line.startswith("{"):
                return json.loads(line)

    def time(self, what):
        self.proc.stdin.write(what + "\n")
        answer = self.read()
        self.times[what].append(answer["seconds"])
        self.cpu[what].append(answer["cpu_seconds"])

    def finish(self):
        self.proc.stdin.write("quit\n")
        self.proc.stdin.flush()
        self.info["final"] = self.read()
        _, status, usage = os.wait4(self.proc.pid, 0)
        self.proc.returncode = os.waitstatus_to_exitcode(status)
        # ru_maxrss is in KiB on Linux
        self.info["peak_rss_bytes"] = usage.ru_maxrss * 1024

    def summary(self):
        steps = self.info["steps"]
        out = dict(self.info)
        for what, ts in self.times.items():
            ms = sorted(t / steps * 1e3 for t in ts)
            out[f"{what}_ms_per_step"] = dict(best=ms[0], median=statistics.median(ms), worst=ms[-1], all=ms)
            out[f"{what}_cpu_s"] = sorted(self.cpu[what])
        out["bwd_over_fwd"] = (out["fwdbwd_ms_per_step"]["best"] - out["fwd_ms_per_step"]["best"]) \
            / out["fwd_ms_per_step"]["best"]
        out["fwdbwd_over_fwd"] = out["fwdbwd_ms_per_step"]["best"] / out["fwd_ms_per_step"]["best"]
        return out


def ratios(ours, peer):
    out = {}
    for what in ("fwd", "fwdbwd"):
        paired = sorted(o / p for o, p in zip(ours.times[what], peer.times[what]))
        out[what] = dict(best_of_each=min(ours.times[what]) / min(peer.times[what]),
                         paired_median=statistics.median(paired), paired_min=paired[0], paired_max=paired[-1])
    return out


def fmt_row(label, s):
    f, b = s["fwd_ms_per_step"], s["fwdbwd_ms_per_step"]
    return (f"  {label:<9} fwd {f['best']:9.3f} ms/step (median {f['median']:.3f}, worst {f['worst']:.3f})   "
            f"fwd+bwd {b['best']:9.3f} (median {b['median']:.3f}, worst {b['worst']:.3f})   "
            f"fwd+bwd/fwd {s['fwdbwd_over_fwd']:.2f}   peak RSS {s['peak_rss_bytes'] / 2**20:.0f} MiB")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--venv", default=os.path.join(ROOT, "target", "flow_peers", "venv"))
    parser.add_argument("--python", help="an interpreter that already has the peers installed, used as it is "
                        "(no venv is made or changed)")
    parser.add_argument("--out", default=os.path.join(ROOT, "out", "flow_peers"))
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--core", type=int, default=0)
    parser.add_argument("--only", help="comma-separated settings: " + ",".join(SETTINGS))
    parser.add_argument("--peers-only", action="store_true", help="measure the peers alone")
    args = parser.parse_args()
    if args.repeats < 1:
        raise SystemExit("--repeats must be at least 1")
    names = args.only.split(",") if args.only else list(SETTINGS)
    for name in names:
        if name not in SETTINGS:
            raise SystemExit(f"unknown setting {name!r}; known: {', '.join(SETTINGS)}")
    os.makedirs(args.out, exist_ok=True)

    python = args.python or venv_python(args.venv)
    if not args.peers_only:
        subprocess.run(["cargo", "build", "--release", "--quiet", "--example", "flow_step"], cwd=ROOT, check=True)

    env = dict(os.environ)
    env.update(XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
               RAYON_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    result = dict(repeats=args.repeats, core=args.core, cpu_count=os.cpu_count(),
                  load_average_start=os.getloadavg(), settings={})
    print(f"load average {result['load_average_start']} on {os.cpu_count()} cores; every process on core "
          f"{args.core}; best of {args.repeats} interleaved repetitions", flush=True)
    for name in names:
        peer_argv, ours_argv, floor = SETTINGS[name]
        t0 = time.time()
        peer = Worker(f"{name} peer", [python, os.path.join(HERE, peer_argv[0])] + peer_argv[1:], env, args.core)
        workers = [peer]
        ours = None
        if not args.peers_only:
            ours = Worker(f"{name} ours", [OURS, "--serve"] + ours_argv, env, args.core)
            workers.append(ours)
        for _ in range(args.repeats):
            for w in workers:
                w.time("fwd")
                w.time("fwdbwd")
        for w in workers:
            w.finish()
        entry = dict(peer=peer.summary(), wall_s=time.time() - t0, load_average=os.getloadavg())
        print(f"{name}: {peer.info['tool']} {peer.info['scene']} {peer.info['resolution']} "
              f"{peer.info['precision']}, {peer.info['steps']} steps per rollout")
        print(fmt_row(peer.info["tool"], entry["peer"]))
        if ours is not None:
            entry["ours"] = ours.summary()
            entry["ours_over_peer"] = ratios(ours, peer)
            entry["floor_fwdbwd"] = floor
            entry["floor_met"] = entry["ours_over_peer"]["fwdbwd"]["best_of_each"] <= floor
            print(fmt_row("diffphys", entry["ours"]))
            for what in ("fwd", "fwdbwd"):
                r = entry["ours_over_peer"][what]
                print(f"  diffphys / {peer.info['tool']} {what:<6}: {r['best_of_each']:.3f} (best of each); "
                      f"paired {r['paired_median']:.3f} [{r['paired_min']:.3f}, {r['paired_max']:.3f}]")
            print(f"  floor fwd+bwd <= {floor}x: {'met' if entry['floor_met'] else 'NOT met'}")
        print(f"  load average {entry['load_average']}", flush=True)
        result["settings"][name] = entry
    result["load_average_end"] = os.getloadavg()
    with open(os.path.join(args.out, "flow_peers.json"), "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
