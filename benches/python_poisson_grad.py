"""The implicit gradient of a Poisson solve called from JAX: diffphys (MG-PCG
in Rust, through jax.pure_callback) against JAX's own conjugate gradient under
jax.lax.custom_linear_solve (the implicit gradient in JAX), in float64 on the
CPU, call overhead included.

Each entrant times ``jax.jit(jax.grad(loss))(b)`` to completion, where
``loss(b) = Σ w·p(b)²`` and ``p = A⁻¹ b``, ``A = -∇²`` (5-point, zero Dirichlet,
h = 1/n): one forward and one adjoint solve, both to the relative residual
``--rtol``. Entrants alternate within each round (interleaved), the best of
``--repeats`` rounds is the figure, the spread is (max - min) / min. The
gradients of the two are compared (relative max difference), and each
solution's true relative residual is reported.

    python benches/python_poisson_grad.py [--sizes 256,1024] [--repeats 7]
        [--preconditioner multigrid|none] [--iterations K]

``--preconditioner none`` runs diffphys' plain CG, the same algorithm as JAX's
(issue 23's like-for-like comparison); the default is MG-PCG.
``--iterations K`` runs exactly K iterations in each solve on both sides (no
tolerance: JAX's ``cg`` with ``tol=0, atol=0, maxiter=K``, diffphys'
``iterations=K``) instead of solving to ``--rtol``.

Prints one JSON line. Needs diffphys (crates/python) and jax installed.
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import diffphys as dp  # noqa: E402
import diffphys.jax as djax  # noqa: E402


def neg_laplacian(p, h):
    """-∇² p with zero Dirichlet walls (the ghost cell mirrors with opposite sign)."""
    out = 0.0
    for axis in (0, 1):
        n = p.shape[axis]
        first = jax.lax.slice_in_dim(p, 0, 1, axis=axis)
        last = jax.lax.slice_in_dim(p, n - 1, n, axis=axis)
        padded = jnp.concatenate([-first, p, -last], axis=axis)
        before = jax.lax.slice_in_dim(padded, 0, n, axis=axis)
        after = jax.lax.slice_in_dim(padded, 2, n + 2, axis=axis)
        out = out + (2.0 * p - before - after) / (h * h)
    return out


def jax_solve(b, h, rtol, iterations=None):
    """p = A⁻¹ b by jax.scipy CG, differentiated implicitly by custom_linear_solve;
    to ``rtol``, or exactly ``iterations`` iterations when given."""
    matvec = lambda x: neg_laplacian(x, h)
    if iterations is None:
        opts = {"tol": rtol, "maxiter": 100_000}
    else:
        opts = {"tol": 0.0, "atol": 0.0, "maxiter": iterations}

    def solve(mv, rhs):
        x, _ = jax.scipy.sparse.linalg.cg(mv, rhs, **opts)
        return x

    return jax.lax.custom_linear_solve(matvec, b, solve, symmetric=True)


def timed(fn, b):
    t0 = time.perf_counter()
    out = fn(b)
    out.block_until_ready()
    return time.perf_counter() - t0, out


def stats(times):
    best = min(times)
    return {
        "best_s": best,
        "median_s": float(np.median(times)),
        "spread": (max(times) - best) / best,
        "runs_s": times,
    }


def measure(n, repeats, rtol, preconditioner, iterations):
    h = 1.0 / n
    rng = np.random.default_rng(n)
    b = jnp.asarray(rng.standard_normal((n, n)))
    w = jnp.asarray(rng.standard_normal((n, n)))
    ours = "diffphys_mgpcg" if preconditioner == "multigrid" else "diffphys_cg"
    if iterations is None:
        opts = {"spacing": (h, h), "rel_tol": rtol, "preconditioner": preconditioner,
                "max_iters": 100_000}
    else:
        opts = {"spacing": (h, h), "preconditioner": preconditioner, "iterations": iterations}
    entrants = {
        ours: jax.jit(
            jax.grad(lambda b: jnp.sum(w * djax.poisson_solve(b, **opts) ** 2))
        ),
        "jax_cg": jax.jit(jax.grad(lambda b: jnp.sum(w * jax_solve(b, h, rtol, iterations) ** 2))),
    }
    grads = {k: timed(f, b)[1] for k, f in entrants.items()}  # compile and warm up
    times = {k: [] for k in entrants}
    for _ in range(repeats):
        for k, f in entrants.items():
            times[k].append(timed(f, b)[0])
    g_dp, g_jax = np.asarray(grads[ours]), np.asarray(grads["jax_cg"])

    def residual(p):
        return float(jnp.linalg.norm(neg_laplacian(p, h) - b) / jnp.linalg.norm(b))

    _, info = dp.poisson(b.shape, **opts).solve(np.asarray(b), return_info=True)
    result = {k: stats(v) for k, v in times.items()}
    result["ratio_diffphys_over_jax"] = result[ours]["best_s"] / result["jax_cg"]["best_s"]
    result["ratio_per_round"] = [a / j for a, j in zip(times[ours], times["jax_cg"])]
    result["gradient_rel_diff"] = float(np.abs(g_dp - g_jax).max() / np.abs(g_jax).max())
    result["residual_diffphys"] = residual(djax.poisson_solve(b, **opts))
    result["residual_jax"] = residual(jax_solve(b, h, rtol, iterations))
    result["diffphys_forward_iterations"] = info["iterations"]
    return result


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="256,1024")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--rtol", type=float, default=1e-8)
    ap.add_argument("--preconditioner", default="multigrid", choices=["multigrid", "none"])
    ap.add_argument("--iterations", type=int, default=None,
                    help="exactly this many CG iterations per solve (no tolerance)")
    args = ap.parse_args()
    if args.iterations is not None and args.iterations < 1:
        ap.error("--iterations must be at least 1")
    sizes = [int(s) for s in args.sizes.split(",")]
    out = {
        "bench": "python_poisson_grad",
        "precision": "f64",
        "rtol": None if args.iterations else args.rtol,
        "iterations": args.iterations,
        "preconditioner": args.preconditioner,
        "repeats": args.repeats,
        "jax": jax.__version__,
        "loadavg_before": os.getloadavg(),
        "cpus": os.cpu_count(),
        "sizes": {},
    }
    for n in sizes:
        out["sizes"][str(n)] = measure(n, args.repeats, args.rtol, args.preconditioner,
                                    args.iterations)
    out["loadavg_after"] = os.getloadavg()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
