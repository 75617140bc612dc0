"""PhiFlow worker for run.py: the PBDL book's wake-flow step (JAX backend, jit).

Scene (the book's "Solver in the loop" KarmanFlow, as the flow-step issue quotes it):
a y-by-x = 2R-by-R staggered grid over 200 x 100 units, open top and bottom
(y), no-slip (sticky) walls left and right (x), a cylinder of radius 10 at
(y, x) = (50, 50), velocity forced to (1, 0) in the band y < 5 each step.
One step: explicit diffusion, the inflow band, semi-Lagrangian self-advection,
make_incompressible with the cylinder and CG to rel 1e-3 / abs 1e-5 from a zero
guess, dt = 1. Viscosity as in the book at Re = 500 with its resolution factor
fixed at 32, so the physical viscosity is the same at every resolution.

Timed: a jit-compiled rollout of --steps steps (forward) and the jit-compiled
gradient of l2_loss(v_final) with respect to the initial velocity (forward +
backward; PhiFlow's implicit gradient of the linear solve). The initial state is
the uniform inflow advanced --warmup steps, so the wake is developing.
Speaks the line protocol of worker_protocol.md.
"""

import argparse
import json
import sys
import time
import warnings

parser = argparse.ArgumentParser()
parser.add_argument("--res", type=int, default=32, help="cells across x (y has twice as many)")
parser.add_argument("--steps", type=int, default=20)
parser.add_argument("--warmup", type=int, default=40)
parser.add_argument("--re", type=float, default=500.0)
parser.add_argument("--f64", action="store_true")
args = parser.parse_args()
warnings.filterwarnings("ignore")

import jax  # noqa: E402
import phi  # noqa: E402
import phiml  # noqa: E402
from phi.jax.flow import (  # noqa: E402
    Box, HardGeometryMask, Obstacle, Solve, Sphere, advect, channel, diffuse, field, fluid, math,
    tensor, vec,
)
from phi.physics._boundaries import OPEN, STICKY, Domain  # noqa: E402

if args.f64:
    math.set_global_precision(64)

R = args.res
CELLS = 2 * R * R
if CELLS > 46340:
    # phiml 1.16.1 packs (row, col) of the pressure matrix into one int32 index and
    # overflows from 46,341 cells; widen it (numerics unchanged) so the grid runs at all.
    import numpy as np
    from phiml.backend._numpy_backend import NumPyBackend

    _ravel = NumPyBackend.ravel_multi_index
    NumPyBackend.ravel_multi_index = (
        lambda self, idx, shape, mode="undefined": _ravel(self, np.asarray(idx).astype(np.int64), shape, mode))

domain = Domain(y=2 * R, x=R, boundaries={"y": (OPEN, OPEN), "x": (STICKY, STICKY)},
                bounds=Box(y=200.0, x=100.0))
# The book's band is Box(y=(None, 5), x=None); with phiflow 3.4 / phiml 1.16 that
# unbounded box rasterises to all ones (every cell forced, a zero gradient), so the
# same band is given with finite bounds.
inflow_mask = domain.staggered_grid(HardGeometryMask(Box(y=(-10.0, 5.0), x=(-10.0, 110.0))))
cylinder = Obstacle(Sphere(center=tensor([50, 50], channel(vector="y,x")), radius=10))
solve = Solve("CG", 1e-3, 1e-5)
dt = 1.0
diffusivity = dt * 32 * 32 / (args.re / (10 / (128 * 128)))


def step(v):
    v = diffuse.explicit(u=v, diffusivity=diffusivity, dt=dt)
    v = v * (1.0 - inflow_mask) + inflow_mask * (1, 0)
    v = advect.semi_lagrangian(v, v, dt=dt)
    v, _ = fluid.make_incompressible(v, [cylinder], solve)
    return v


def rollout(v):
    for _ in range(args.steps):
        v = step(v)
    return v


def loss(v0):
    return field.l2_loss(rollout(v0))


def wait(x):
    values = x.values
    parts = math.unstack(values, values.shape.non_uniform_shape) if values.shape.is_non_uniform else [values]
    for t in parts:
        jax.block_until_ready(t.native(t.shape))
    return x


one_step = math.jit_compile(step)
v0 = domain.staggered_grid(vec(y=1.0, x=0.0))
for _ in range(args.warmup):
    v0 = one_step(v0)
wait(v0)

# Pressure iterations per step, read eagerly (the jit path does not report them).
with math.SolveTape() as solves:
    v = v0
    for _ in range(2):
        v = step(v)
iterations = [int(math.max(s.iterations)) for s in solves.solves]

forward = math.jit_compile(rollout)
gradient = math.jit_compile(math.gradient(loss, "v0", get_output=True))


def run_fwd():
    return wait(forward(v0))


def run_fwdbwd():
    _, g = gradient(v0)
    return wait(g[0] if isinstance(g, (list, tuple)) else g)


t = time.perf_counter()
for _ in range(2):
    v_final = run_fwd()
compile_fwd = time.perf_counter() - t
t = time.perf_counter()
for _ in range(2):
    g = run_fwdbwd()
compile_fwdbwd = time.perf_counter() - t

print(json.dumps(dict(
    ready=True, tool="phiflow", scene="wake", resolution=f"{R}x{2 * R}", cells=CELLS,
    precision="f64" if args.f64 else "f32", steps=args.steps, warmup_steps=args.warmup, dt=dt,
    diffusivity=diffusivity, solve="CG rel 1e-3 abs 1e-5, zero guess", cg_iterations_per_step=iterations,
    int64_index_patch=CELLS > 46340, first_two_calls_s=dict(fwd=compile_fwd, fwdbwd=compile_fwdbwd),
    loss=float(field.l2_loss(v_final)), max_abs_divergence=float(math.max(abs(field.divergence(v_final).values))),
    grad_norm=float(math.sqrt(math.sum(g.values ** 2, g.values.shape))),
    versions=dict(phiflow=phi.__version__, phiml=phiml.__version__, jax=jax.__version__),
)), flush=True)

for line in sys.stdin:
    what = line.strip()
    if what == "quit":
        break
    run = {"fwd": run_fwd, "fwdbwd": run_fwdbwd}[what]
    t, c = time.perf_counter(), time.process_time()
    run()
    print(json.dumps(dict(what=what, seconds=time.perf_counter() - t, cpu_seconds=time.process_time() - c)),
          flush=True)
print(json.dumps(dict(done=True)), flush=True)
