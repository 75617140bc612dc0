"""JAX-CFD worker for run.py: the periodic Taylor-Green box.

Scene: [0, 2 pi]^2 periodic, N x N cells, u = sin x cos y, v = -cos x sin y,
density 1, viscosity 1e-3, dt = stable_time_step(max velocity 1, CFL 0.5), the
library's standard step `semi_implicit_navier_stokes` (van Leer advection,
explicit diffusion, projection with the FFT-diagonalised pressure solve).

Timed: the jit-compiled rollout of --steps steps (lax.scan via
funcutils.repeated), and the jit-compiled VJP of the same rollout with the final
state as cotangent (the gradient of 0.5 * |v_final|^2), forward plus backward.
Speaks the line protocol of worker_protocol.md.
"""

import argparse
import json
import os
import sys
import time

parser = argparse.ArgumentParser()
parser.add_argument("--n", type=int, default=128)
parser.add_argument("--steps", type=int, default=100)
parser.add_argument("--viscosity", type=float, default=1e-3)
parser.add_argument("--f64", action="store_true")
args = parser.parse_args()
if args.f64:
    os.environ["JAX_ENABLE_X64"] = "1"

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

if args.f64:
    jax.config.update("jax_enable_x64", True)
import jax_cfd.base as cfd  # noqa: E402

grid = cfd.grids.Grid((args.n, args.n), domain=((0.0, 2 * jnp.pi), (0.0, 2 * jnp.pi)))
dt = cfd.equations.stable_time_step(1.0, 0.5, args.viscosity, grid)
v0 = cfd.initial_conditions.initial_velocity_field(
    (lambda x, y: jnp.sin(x) * jnp.cos(y), lambda x, y: -jnp.cos(x) * jnp.sin(y)), grid)
step = cfd.equations.semi_implicit_navier_stokes(
    density=1.0, viscosity=args.viscosity, dt=dt, grid=grid, pressure_solve=cfd.pressure.solve_fast_diag)
rollout = cfd.funcutils.repeated(step, args.steps)


def vjp_of_final(v):
    v_final, pullback = jax.vjp(rollout, v)
    return pullback(v_final)[0]


forward = jax.jit(rollout)
gradient = jax.jit(vjp_of_final)


def wait(tree):
    return jax.tree_util.tree_map(lambda a: a.block_until_ready() if hasattr(a, "block_until_ready") else a, tree)


def energy(v):
    return float(sum(np.sum(np.asarray(u.data, np.float64) ** 2) for u in v))


t = time.perf_counter()
for _ in range(2):
    v_final = wait(forward(v0))
compile_fwd = time.perf_counter() - t
t = time.perf_counter()
for _ in range(2):
    g = wait(gradient(v0))
compile_fwdbwd = time.perf_counter() - t

print(json.dumps(dict(
    ready=True, tool="jax-cfd", scene="periodic Taylor-Green box", resolution=f"{args.n}x{args.n}",
    cells=args.n * args.n, precision="f64" if args.f64 else "f32", dtype=str(v0[0].data.dtype),
    steps=args.steps, dt=float(dt), viscosity=args.viscosity, pressure_solve="fast_diag (FFT, direct)",
    first_two_calls_s=dict(fwd=compile_fwd, fwdbwd=compile_fwdbwd),
    kinetic_energy_ratio=energy(v_final) / energy(v0), grad_norm=energy(g) ** 0.5,
    max_abs_divergence=float(jnp.max(jnp.abs(cfd.finite_differences.divergence(v_final).data))),
    versions=dict(jax=jax.__version__),
)), flush=True)

for line in sys.stdin:
    what = line.strip()
    if what == "quit":
        break
    run = {"fwd": forward, "fwdbwd": gradient}[what]
    t, c = time.perf_counter(), time.process_time()
    wait(run(v0))
    print(json.dumps(dict(what=what, seconds=time.perf_counter() - t, cpu_seconds=time.process_time() - c)),
          flush=True)
print(json.dumps(dict(done=True)), flush=True)
