"""JAX on the same problems as the diffphys harness, for a side-by-side anchor.

The scene is the harness's default one (crates/compare/src/problem.rs):
A = −∇² on n × n cells of width h = 1/n with zero Dirichlet walls, the same
right-hand side b and target p*, loss L(b) = ½‖x(b) − p*‖² with x(b) from CG,
float64. Measured, each as the median of --repeats runs after one warm-up
(which includes compilation):

- implicit: jax.grad through jax.scipy.sparse.linalg.cg with a fixed number
  of iterations (tol=0), whose VJP is one more CG solve (custom_linear_solve);
- naive: jax.grad through the same number of CG iterations written as a
  lax.fori_loop, differentiated by reverse mode through every iteration;
- per-iteration time of a CG solve (forward only) at each --cg-sizes size.

It ends its stdout with one JSON line. Without JAX installed it says so and
exits 0 (JAX is never a dependency of the build or the tests):

    pip install "jax[cpu]"
    python3 benches/anchors/jax_cg.py            # 256², 800 iterations; CG at 256² and 1024²
    python3 benches/anchors/side_by_side.py      # JAX and diffphys in one table and chart
"""

import argparse
import json
import math
import os
import statistics
import sys
import time


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=256, help="grid size of the gradient runs")
    parser.add_argument("--iterations", type=int, default=800, help="fixed CG iterations")
    parser.add_argument("--cg-sizes", default="256,1024", help="sizes of the per-iteration timing")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    try:
        import jax
        import jax.numpy as jnp
        from jax import lax
    except ImportError:
        print("JAX is not installed (pip install 'jax[cpu]'); skipping the JAX anchor")
        print(json.dumps({"skipped": "jax not installed"}))
        return 0
    jax.config.update("jax_enable_x64", True)

    def scene(n):
        h = 1.0 / n
        c = (jnp.arange(n) + 0.5) / n
        x, y = jnp.meshgrid(c, c, indexing="ij")
        gauss = lambda cx, cy, w: jnp.exp(-((x - cx) ** 2 + (y - cy) ** 2) / w)
        b = 20.0 * gauss(0.3, 0.6, 0.02) - 12.0 * gauss(0.7, 0.3, 0.03) + 4.0 * jnp.sin(
            3 * math.pi * x
        ) * jnp.sin(math.pi * y)
        target = 0.05 * jnp.sin(math.pi * x) * jnp.sin(2 * math.pi * y)

        # −∇² with zero Dirichlet walls: a ghost cell holds −p, so each wall face
        # adds p to the diagonal; neighbours past the wall are zero-padded.
        walls = jnp.zeros((n, n)).at[0].add(1).at[-1].add(1).at[:, 0].add(1).at[:, -1].add(1)
        diagonal = (4.0 + walls) / (h * h)

        def apply(p):
            padded = jnp.pad(p, 1)
            neighbours = padded[:-2, 1:-1] + padded[2:, 1:-1] + padded[1:-1, :-2] + padded[1:-1, 2:]
            return diagonal * p - neighbours / (h * h)

        return apply, b, target

    def timed(f, *a):
        jax.block_until_ready(f(*a))  # warm-up and compilation
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            jax.block_until_ready(f(*a))
            times.append(time.perf_counter() - start)
        return statistics.median(times)

    k = args.iterations
    apply, b, target = scene(args.n)

    def loss_implicit(b):
        x, _ = jax.scipy.sparse.linalg.cg(apply, b, tol=0.0, atol=0.0, maxiter=k)
        return 0.5 * jnp.sum((x - target) ** 2)

    def cg_unrolled(b, iterations):
        def body(_, state):
            x, r, p, rr = state
            ap = apply(p)
            alpha = rr / jnp.vdot(p, ap)
            x = x + alpha * p
            r = r - alpha * ap
            rr_new = jnp.vdot(r, r)
            p = r + (rr_new / rr) * p
            return x, r, p, rr_new

        x0 = jnp.zeros_like(b)
        state = (x0, b, b, jnp.vdot(b, b))
        return lax.fori_loop(0, iterations, body, state)[0]

    def loss_naive(b):
        return 0.5 * jnp.sum((cg_unrolled(b, k) - target) ** 2)

    grad_implicit = jax.jit(jax.grad(loss_implicit))
    grad_naive = jax.jit(jax.grad(loss_naive))
    t_implicit = timed(grad_implicit, b)
    t_naive = timed(grad_naive, b)
    g_i, g_n = grad_implicit(b), grad_naive(b)
    rel_diff = float(jnp.linalg.norm(g_i - g_n) / jnp.linalg.norm(g_i))
    print(f"JAX {jax.__version__} on {jax.devices()[0].platform}, {os.cpu_count()} cores")
    print(f"{args.n}², {k} CG iterations: implicit gradient {t_implicit:.4f} s, "
          f"naive (fori_loop) gradient {t_naive:.4f} s; |g_implicit − g_naive|/|g| = {rel_diff:.2e}")

    per_iteration = {}
    for n in [int(s) for s in args.cg_sizes.split(",")]:
        apply_n, b_n, _ = scene(n)
        iters = 200
        solve = jax.jit(lambda b: jax.scipy.sparse.linalg.cg(apply_n, b, tol=0.0, atol=0.0, maxiter=iters)[0])
        t = timed(solve, b_n) / iters
        per_iteration[str(n)] = t
        print(f"CG at {n}²: {t * 1e6:.1f} µs per iteration")

    print(json.dumps({
        "jax_version": jax.__version__,
        "n": args.n,
        "iterations": k,
        "seconds_implicit_gradient": t_implicit,
        "seconds_naive_gradient": t_naive,
        "gradient_rel_diff_implicit_vs_naive": rel_diff,
        "seconds_per_cg_iteration": per_iteration,
        "repeats": args.repeats,
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
