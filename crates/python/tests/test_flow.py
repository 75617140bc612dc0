"""The flow step: torch gradcheck in f64 through several steps (velocity,
pressure, viscosity), JAX's gradient equal to PyTorch's, and the drag's
gradient against central differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

import diffphys as dp
import diffphys.jax as djax
import diffphys.torch as dtorch


def box():
    return dp.FlowStep((8, 6), (1.0, 0.75), viscosity=0.02, dt=0.02)


def channel():
    solid = np.zeros((16, 8), bool)
    solid[5:7, 3:5] = True
    return dp.FlowStep((16, 8), (2.0, 1.0), sides="channel", inflow=1.0, obstacle=solid,
                       viscosity=0.05, dt=0.02)


def velocity(scene, seed, amplitude=0.3):
    rng = np.random.default_rng(seed)
    return (amplitude * rng.standard_normal(scene.shape_x),
            amplitude * rng.standard_normal(scene.shape_y))


def test_channel_drag_and_symmetry():
    scene = channel()
    ux, uy = np.zeros(scene.shape_x), np.zeros(scene.shape_y)
    vx, vy, p, force = scene.forward(ux, uy, steps=10)
    assert vx.shape == scene.shape_x and p.shape == scene.shape
    assert abs(force[0]) > 0 and abs(force[1]) < 1e-9 * abs(force[0])  # symmetric body: no lift
    # Ten single steps, the pressure carried, are the same as steps=10.
    s = (ux, uy, None)
    for _ in range(10):
        a, b, q, f = scene.forward(s[0], s[1], pressure=s[2])
        s = (a, b, q)
    np.testing.assert_allclose(s[0], vx, rtol=0, atol=1e-12)
    np.testing.assert_allclose(f, force, rtol=1e-12)


@pytest.mark.parametrize("steps", [1, 3])
def test_torch_gradcheck(steps):
    scene = box()
    ux, uy = (torch.tensor(a, requires_grad=True) for a in velocity(scene, steps))
    p = torch.tensor(0.1 * np.random.default_rng(9).standard_normal(scene.shape), requires_grad=True)
    nu = torch.tensor(0.02, dtype=torch.float64, requires_grad=True)
    f = lambda ux, uy, p, nu: dtorch.flow_step(scene, ux, uy, steps=steps, pressure=p, viscosity=nu)[:3]
    assert torch.autograd.gradcheck(f, (ux, uy, p, nu), eps=1e-6, atol=1e-8, rtol=1e-6)


def test_jax_gradient_equals_torch_and_jits():
    scene = channel()
    ux, uy = velocity(scene, 3, 0.1)
    c = np.random.default_rng(4).standard_normal(scene.shape_x)

    def jloss(ux, uy, nu):
        vx, vy, p, force = djax.flow_step(scene, ux, uy, steps=4, viscosity=nu)
        return jnp.sum(c * vx**2) + force[0]

    g = jax.jit(jax.grad(jloss, argnums=(0, 1, 2)))(jnp.asarray(ux), jnp.asarray(uy), 0.05)
    tx, ty = torch.tensor(ux, requires_grad=True), torch.tensor(uy, requires_grad=True)
    tnu = torch.tensor(0.05, dtype=torch.float64, requires_grad=True)
    vx, vy, p, force = dtorch.flow_step(scene, tx, ty, steps=4, viscosity=tnu)
    ((torch.tensor(c) * vx**2).sum() + force[0]).backward()
    for a, b in zip(g, (tx.grad, ty.grad, tnu.grad)):
        np.testing.assert_allclose(np.asarray(a), b.numpy(), rtol=1e-12, atol=1e-14)


def test_drag_gradient_in_viscosity_against_central_differences():
    scene = channel()
    ux, uy = np.zeros(scene.shape_x), np.zeros(scene.shape_y)
    drag = lambda nu: scene.forward(ux, uy, steps=5, viscosity=nu)[3][0]
    g = scene.vjp(ux, uy, None, None, None, np.array([1.0, 0.0]), steps=5, viscosity=0.05)[3]
    h = 1e-6
    fd = (drag(0.05 + h) - drag(0.05 - h)) / (2 * h)
    assert abs(g - fd) <= 1e-6 * abs(fd)


def test_flow_errors():
    with pytest.raises(dp.InvalidArgumentError, match="viscosity"):
        dp.FlowStep((8, 8), (1.0, 1.0), viscosity=-1.0)
    with pytest.raises(dp.InvalidArgumentError, match="side"):
        dp.FlowStep((8, 8), (1.0, 1.0), sides={"left": "sticky"})
    scene = box()
    with pytest.raises(dp.ShapeError):
        scene.forward(np.zeros((3, 3)), np.zeros(scene.shape_y))
    ux, uy = velocity(scene, 1)
    ux[2, 2] = np.nan
    with pytest.raises(dp.NonFiniteError):
        scene.forward(ux, uy)


def test_vjp_keeps_its_buffers_and_gives_the_same_gradients():
    # 40 x 32 cells: fields long enough for the buffer pool
    scene = dp.FlowStep((40, 32), (1.0, 0.8), viscosity=0.01, dt=0.01, pressure_solver="fourier")
    ux, uy = velocity(scene, 5)
    gx, gy = velocity(scene, 6, amplitude=1.0)
    assert scene.held_bytes == 0
    first = scene.vjp(ux, uy, gx, gy, steps=4, checkpoint_every=1)
    assert scene.held_bytes > 0
    again = scene.vjp(ux, uy, gx, gy, steps=4, checkpoint_every=1)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    scene.release_buffers()
    assert scene.held_bytes == 0
    kept_nothing = dp.FlowStep((40, 32), (1.0, 0.8), viscosity=0.01, dt=0.01,
                               pressure_solver="fourier", buffer_limit_bytes=0)
    alone = kept_nothing.vjp(ux, uy, gx, gy, steps=4, checkpoint_every=1)
    assert kept_nothing.held_bytes == 0
    for a, b in zip(first, alone):
        np.testing.assert_array_equal(a, b)
