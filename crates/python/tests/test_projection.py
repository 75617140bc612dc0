"""Pressure projection with an obstacle: divergence-free, idempotent, its
gradient against a pure-JAX reference and torch gradcheck."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

import diffphys as dp
import diffphys.jax as djax
import diffphys.torch as dtorch
from reference import mac_gradient_matrix, project

SHAPE = (9, 7)
SPACING = (0.5, 0.4)


def obstacle():
    solid = np.zeros(SHAPE, bool)
    solid[3:5, 2:4] = True
    return solid


def velocities(seed, dtype=np.float64):
    proj = dp.projection(SHAPE, spacing=SPACING, obstacle=obstacle())
    rng = np.random.default_rng(seed)
    return (
        rng.standard_normal(proj.shape_x).astype(dtype),
        rng.standard_normal(proj.shape_y).astype(dtype),
    )


def test_divergence_free_and_idempotent():
    ux, uy = velocities(1)
    proj = dp.Projection(SHAPE, spacing=SPACING, obstacle=obstacle(), rel_tol=1e-12)
    vx, vy, p = proj.project(ux, uy)
    G, w = mac_gradient_matrix(SHAPE, SPACING, obstacle())
    div = -G.T @ np.concatenate([vx.ravel(), vy.ravel()])
    assert np.abs(div).max() < 1e-9
    wx, wy, _ = proj.project(vx, vy)
    np.testing.assert_allclose(wx, vx, atol=1e-9)
    np.testing.assert_allclose(wy, vy, atol=1e-9)
    assert np.all(p[obstacle()] == 0.0)


def test_float32():
    ux, uy = velocities(2, np.float32)
    vx, vy, p = dp.project(ux, uy, shape=SHAPE, spacing=SPACING, obstacle=obstacle())
    assert vx.dtype == vy.dtype == p.dtype == np.float32


def test_jax_grad_matches_pure_jax_reference():
    ux, uy = map(jnp.asarray, velocities(3))
    G, w = mac_gradient_matrix(SHAPE, SPACING, obstacle())
    rng = np.random.default_rng(4)
    cx, cy = jnp.asarray(rng.standard_normal(ux.shape)), jnp.asarray(rng.standard_normal(uy.shape))
    cp = jnp.asarray(rng.standard_normal(SHAPE))

    def loss(outputs):
        vx, vy, p = outputs
        return jnp.sum(cx * vx**2) + jnp.sum(cy * vy) + jnp.sum(cp * p**2)

    ours = lambda ux, uy: loss(
        djax.project(ux, uy, shape=SHAPE, spacing=SPACING, obstacle=obstacle(), rel_tol=1e-13)
    )
    reference = lambda ux, uy: loss(project(ux, uy, G, w, SHAPE))
    assert abs(ours(ux, uy) - reference(ux, uy)) <= 1e-8 * abs(reference(ux, uy))
    g = jax.grad(ours, argnums=(0, 1))(ux, uy)
    g_ref = jax.grad(reference, argnums=(0, 1))(ux, uy)
    scale = max(np.abs(a).max() for a in g_ref)
    for a, b in zip(g, g_ref):
        assert np.abs(a - b).max() <= 1e-8 * scale
    g_jit = jax.jit(jax.grad(ours, argnums=(0, 1)))(ux, uy)
    for a, b in zip(g_jit, g):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * scale)


@pytest.mark.parametrize("with_obstacle", [False, True])
def test_torch_gradcheck(with_obstacle):
    kw = dict(shape=SHAPE, spacing=SPACING, rel_tol=1e-13)
    if with_obstacle:
        kw["obstacle"] = obstacle()
    ux, uy = (torch.tensor(a, requires_grad=True) for a in velocities(5))
    assert torch.autograd.gradcheck(
        lambda ux, uy: dtorch.project(ux, uy, **kw), (ux, uy), eps=1e-6, atol=1e-8, rtol=1e-6
    )
