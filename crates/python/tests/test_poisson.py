"""The Poisson solve from numpy, JAX and PyTorch: residual, implicit gradient
against JAX's own CG, torch gradcheck, jit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

import diffphys as dp
import diffphys.jax as djax
import diffphys.torch as dtorch
from reference import neg_laplacian


@pytest.mark.parametrize("boundary", ["dirichlet", ("dirichlet", "closed"), "closed", "periodic"])
def test_solution_satisfies_the_equation(boundary):
    rng = np.random.default_rng(1)
    b = rng.standard_normal((24, 20))
    spacing = (0.1, 0.2)
    p = dp.poisson_solve(b, spacing=spacing, boundary=boundary, rel_tol=1e-12)
    bx, by = (boundary, boundary) if isinstance(boundary, str) else boundary
    if "dirichlet" not in (bx, by):
        b = b - b.mean()  # singular: the solve is of the projected right-hand side
        assert abs(p.mean()) < 1e-12
    residual = _neg_laplacian(p, spacing, (bx, by)) - b
    assert np.linalg.norm(residual) <= 1e-10 * np.linalg.norm(b)


def _neg_laplacian(p, spacing, boundaries):
    """-∇² with a boundary per axis (the reference takes one for both)."""
    out = 0.0
    for axis, (h, bnd) in enumerate(zip(spacing, boundaries)):
        one = [h if a == axis else np.inf for a in range(2)]
        out = out + np.asarray(neg_laplacian(jnp.asarray(p), tuple(one), bnd))
    return out


@pytest.mark.parametrize("preconditioner", ["multigrid", "jacobi", "none"])
def test_preconditioners_agree(preconditioner):
    b = np.random.default_rng(2).standard_normal((32, 32))
    p = dp.poisson_solve(b, preconditioner=preconditioner, rel_tol=1e-12)
    ref = dp.poisson_solve(b, preconditioner="multigrid", rel_tol=1e-12)
    np.testing.assert_allclose(p, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


def test_float32_in_float32_out():
    b = np.random.default_rng(3).standard_normal((32, 32)).astype(np.float32)
    p, info = dp.Poisson((32, 32)).solve(b, return_info=True)
    assert p.dtype == np.float32 and info["converged"] and info["iterations"] > 0
    ref = dp.poisson_solve(b.astype(np.float64))
    assert np.abs(p - ref).max() <= 1e-4 * np.abs(ref).max()


def test_multigrid_iterations_stay_flat():
    its = []
    for n in (32, 128):
        b = np.random.default_rng(n).standard_normal((n, n))
        _, info = dp.Poisson((n, n)).solve(b, return_info=True)
        its.append(info["iterations"])
    assert its[1] <= its[0] + 4, its


def test_jax_grad_matches_jax_cg_reference():
    n, spacing = 16, (1.0 / 16, 1.0 / 16)
    rng = np.random.default_rng(4)
    b = jnp.asarray(rng.standard_normal((n, n)))
    w = jnp.asarray(rng.standard_normal((n, n)))

    def ours(b):
        p = djax.poisson_solve(b, spacing=spacing, rel_tol=1e-13)
        return jnp.sum(w * p**2)

    def reference(b):
        matvec = lambda x: neg_laplacian(x, spacing)
        p, _ = jax.scipy.sparse.linalg.cg(matvec, b, tol=1e-14, maxiter=10_000)
        return jnp.sum(w * p**2)

    g, g_ref = jax.grad(ours)(b), jax.grad(reference)(b)
    assert np.abs(ours(b) - reference(b)) <= 1e-8 * np.abs(reference(b))
    assert np.abs(g - g_ref).max() <= 1e-8 * np.abs(g_ref).max()
    # jit compiles through the callback and gives the same gradient.
    g_jit = jax.jit(jax.grad(ours))(b)
    np.testing.assert_allclose(g_jit, g, rtol=0, atol=1e-14 * np.abs(g).max())


def test_fixed_iterations_match_jax_cg_with_the_same_count():
    n, k, spacing = 16, 12, (1.0 / 16, 1.0 / 16)
    b = np.random.default_rng(6).standard_normal((n, n))
    solver = dp.poisson((n, n), spacing=spacing, preconditioner="none", iterations=k)
    p, info = solver.solve(b, return_info=True)
    assert info["iterations"] == k and not info["converged"]
    matvec = lambda x: neg_laplacian(x, spacing)
    ref, _ = jax.scipy.sparse.linalg.cg(matvec, jnp.asarray(b), tol=0.0, atol=0.0, maxiter=k)
    # k iterations of the same recurrence: equal up to rounding, and far from
    # the converged solution (so the count is what is compared).
    np.testing.assert_allclose(p, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    converged = dp.poisson_solve(b, spacing=spacing, rel_tol=1e-12)
    assert np.abs(p - converged).max() > 1e-3 * np.abs(converged).max()
    with pytest.raises(dp.InvalidArgumentError, match="rel_tol"):
        dp.poisson((n, n), iterations=k, rel_tol=1e-8)
    with pytest.raises(dp.InvalidArgumentError, match="at least 1"):
        dp.poisson((n, n), iterations=0)


def test_jax_vmap_runs_per_element():
    bs = jnp.asarray(np.random.default_rng(5).standard_normal((3, 8, 8)))
    ps = jax.vmap(djax.poisson_solve)(bs)
    for b, p in zip(bs, ps):
        np.testing.assert_allclose(p, dp.poisson_solve(np.asarray(b)), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("boundary", ["dirichlet", "closed"])
def test_torch_gradcheck(boundary):
    b = torch.randn(8, 6, dtype=torch.float64, requires_grad=True)
    f = lambda b: dtorch.poisson_solve(b, spacing=(0.5, 0.25), boundary=boundary, rel_tol=1e-13)
    assert torch.autograd.gradcheck(f, (b,), eps=1e-6, atol=1e-8, rtol=1e-6)


def test_torch_float32_backward():
    b = torch.randn(16, 16, requires_grad=True)
    dtorch.poisson_solve(b).pow(2).sum().backward()
    assert b.grad.dtype == torch.float32 and torch.isfinite(b.grad).all()
