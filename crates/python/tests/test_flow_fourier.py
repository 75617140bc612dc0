"""The flow step's Fourier pressure solve and the VJP's checkpoint choice from
Python: the same answers as the sparse Cholesky solve and the default
schedule, and typed errors where they do not apply."""

import numpy as np
import pytest

import diffphys as dp


def box(solver):
    return dp.FlowStep((12, 8), (1.0, 0.75), viscosity=0.02, dt=0.02, pressure_solver=solver)


def velocity(scene, seed, amplitude=0.3):
    rng = np.random.default_rng(seed)
    return (amplitude * rng.standard_normal(scene.shape_x),
            amplitude * rng.standard_normal(scene.shape_y))


def test_fourier_steps_match_cholesky_steps():
    fft, chol = box("fourier"), box("cholesky")
    ux, uy = velocity(fft, 3)
    a = fft.forward(ux, uy, steps=5)
    b = chol.forward(ux, uy, steps=5)
    moved = np.abs(a[0] - ux).max()
    assert moved > 1e-3, "the steps must change the velocity"
    for x, y in zip(a[:3], b[:3]):
        assert np.abs(x - y).max() <= 1e-12 * max(1.0, np.abs(y).max())


def test_vjp_keeping_every_step_equals_the_checkpointed_vjp():
    scene = box("fourier")
    ux, uy = velocity(scene, 5)
    gx, gy = velocity(scene, 6, amplitude=1.0)
    full = scene.vjp(ux, uy, gx, gy, steps=9, checkpoint_every=1)
    default = scene.vjp(ux, uy, gx, gy, steps=9)
    every4 = scene.vjp(ux, uy, gx, gy, steps=9, checkpoint_every=4)
    assert np.abs(full[0]).max() > 0
    for a, b, c in zip(full, default, every4):
        a, b, c = np.asarray(a), np.asarray(b), np.asarray(c)
        if a.size == 0:  # the inflow profile of a box without inflow
            continue
        assert np.abs(a - b).max() <= 1e-12 * max(1.0, np.abs(a).max())
        assert np.abs(a - c).max() <= 1e-12 * max(1.0, np.abs(a).max())


def test_fourier_and_checkpoint_errors():
    solid = np.zeros((12, 8), bool)
    solid[4:6, 3:5] = True
    with pytest.raises(dp.InvalidArgumentError, match="Fourier"):
        dp.FlowStep((12, 8), (1.0, 0.75), obstacle=solid, pressure_solver="fourier")
    with pytest.raises(dp.InvalidArgumentError, match="Fourier"):
        dp.FlowStep((12, 8), (1.0, 0.75), sides="cavity", pressure_solver="fourier")
    scene = box("fourier")
    ux, uy = velocity(scene, 7)
    with pytest.raises(dp.InvalidArgumentError, match="checkpoint_every"):
        scene.vjp(ux, uy, ux, uy, steps=3, checkpoint_every=0)
