"""Training loops that call a diffphys solve inside the loss (the README's
"From Python" snippets): the source whose potential matches a target."""

import jax
import jax.numpy as jnp
import numpy as np
import torch

import diffphys.jax as djax
import diffphys.torch as dtorch

N = 32
H = (1.0 / N, 1.0 / N)


def target_source():
    x = (np.arange(N) + 0.5) / N
    X, Y = np.meshgrid(x, x, indexing="ij")
    return 50.0 * np.exp(-((X - 0.3) ** 2 + (Y - 0.6) ** 2) / 0.02)


def test_jax_training_loop():
    p_target = djax.poisson_solve(jnp.asarray(target_source()), spacing=H)

    @jax.jit
    def step(b):
        loss, g = jax.value_and_grad(
            lambda b: jnp.mean((djax.poisson_solve(b, spacing=H) - p_target) ** 2)
        )(b)
        return b - 2e5 * g, loss

    b = jnp.zeros((N, N))
    losses = []
    for _ in range(30):
        b, loss = step(b)
        losses.append(float(loss))
    assert losses[-1] < 1e-2 * losses[0], losses


def test_torch_training_loop():
    with torch.no_grad():
        p_target = dtorch.poisson_solve(torch.tensor(target_source()), spacing=H)
    b = torch.zeros(N, N, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.SGD([b], lr=2e5)
    losses = []
    for _ in range(30):
        opt.zero_grad()
        loss = (dtorch.poisson_solve(b, spacing=H) - p_target).pow(2).mean()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 1e-2 * losses[0], losses
