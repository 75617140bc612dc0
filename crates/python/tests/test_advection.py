"""Semi-Lagrangian and upwind advection: values and gradients against pure-JAX
references, torch gradcheck."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

import diffphys as dp
import diffphys.jax as djax
import diffphys.torch as dtorch
import reference

SHAPE = (10, 8)
SPACING = (0.5, 0.25)
DT = 0.1

SCHEMES = {
    "semi_lagrangian2": (dp.semi_lagrangian2, djax.semi_lagrangian2, dtorch.semi_lagrangian2,
                         reference.semi_lagrangian2),
    "upwind2": (dp.upwind2, djax.upwind2, dtorch.upwind2, reference.upwind2),
}


def fields(seed, dtype=np.float64):
    rng = np.random.default_rng(seed)
    d = rng.standard_normal(SHAPE).astype(dtype)
    u = 0.5 * rng.standard_normal((2, *SHAPE)).astype(dtype)
    return d, u


@pytest.mark.parametrize("name", SCHEMES)
def test_forward_matches_reference(name):
    plain, _, _, ref = SCHEMES[name]
    d, u = fields(1)
    out = plain(d, u, dt=DT, spacing=SPACING)
    np.testing.assert_allclose(out, ref(jnp.asarray(d), jnp.asarray(u), DT, SPACING), atol=1e-13)
    out32 = plain(d.astype(np.float32), u.astype(np.float32), dt=DT, spacing=SPACING)
    assert out32.dtype == np.float32
    np.testing.assert_allclose(out32, out, atol=1e-5)


@pytest.mark.parametrize("name", SCHEMES)
def test_jax_grad_matches_reference(name):
    _, jfn, _, ref = SCHEMES[name]
    d, u = map(jnp.asarray, fields(2))
    c = jnp.asarray(np.random.default_rng(3).standard_normal(SHAPE))
    ours = lambda d, u: jnp.sum(c * jfn(d, u, dt=DT, spacing=SPACING) ** 2)
    theirs = lambda d, u: jnp.sum(c * ref(d, u, DT, SPACING) ** 2)
    g = jax.grad(ours, argnums=(0, 1))(d, u)
    g_ref = jax.grad(theirs, argnums=(0, 1))(d, u)
    for a, b in zip(g, g_ref):
        assert np.abs(a - b).max() <= 1e-8 * np.abs(b).max()
    g_jit = jax.jit(jax.grad(ours, argnums=(0, 1)))(d, u)
    for a, b in zip(g_jit, g):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)


@pytest.mark.parametrize("name", SCHEMES)
def test_torch_gradcheck(name):
    _, _, tfn, _ = SCHEMES[name]
    d, u = (torch.tensor(a, requires_grad=True) for a in fields(4))
    f = lambda d, u: tfn(d, u, dt=DT, spacing=SPACING)
    assert torch.autograd.gradcheck(f, (d, u), eps=1e-6, atol=1e-8, rtol=1e-6)
