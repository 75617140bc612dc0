"""Pure-JAX references of the wrapped operators, written from their formulas
(crates/ops docs), for the gradient comparisons."""

import jax.numpy as jnp
import numpy as np


def _ghosts(p, axis, boundary):
    """The cells before the first and after the last along ``axis``."""
    n = p.shape[axis]
    first = jnp.take(p, jnp.array([0]), axis=axis)
    last = jnp.take(p, jnp.array([n - 1]), axis=axis)
    if boundary == "periodic":
        return last, first
    if boundary == "dirichlet":  # the wall value is zero: the ghost mirrors with opposite sign
        return -first, -last
    if boundary == "closed":  # zero normal derivative
        return first, last
    raise ValueError(boundary)


def neg_laplacian(p, spacing=(1.0, 1.0), boundary="dirichlet"):
    """``-∇² p``, 5-point, with ghost cells from the boundary."""
    out = 0.0
    for axis, h in enumerate(spacing):
        lo, hi = _ghosts(p, axis, boundary)
        padded = jnp.concatenate([lo, p, hi], axis=axis)
        n = p.shape[axis]
        before = jnp.take(padded, jnp.arange(0, n), axis=axis)
        after = jnp.take(padded, jnp.arange(2, n + 2), axis=axis)
        out = out + (2.0 * p - before - after) / (h * h)
    return out


def mac_gradient_matrix(shape, spacing=(1.0, 1.0), obstacle=None):
    """The face gradient ``G`` of a MAC grid with closed walls as a dense
    matrix (rows: x-faces ``[nx+1, ny]`` then y-faces ``[nx, ny+1]``,
    row-major, face ``f`` between cells ``f-1`` and ``f``; columns: cells),
    the wall faces and a face touching an obstacle cell closed (weight 0).
    Returns ``(G, w)`` with ``w`` the face weights."""
    nx, ny = shape
    dx, dy = spacing
    solid = np.zeros(shape, bool) if obstacle is None else np.asarray(obstacle, bool)
    rows, weights = [], []

    def face(lo, hi, closed, h):
        w = 0.0 if closed else 1.0
        r = np.zeros(nx * ny)
        if w:
            r[hi], r[lo] = w / h, -w / h
        rows.append(r)
        weights.append(w)

    for f in range(nx + 1):
        for j in range(ny):
            wall = f == 0 or f == nx
            closed = wall or solid[f - 1, j] or solid[f, j]
            face((f - 1) * ny + j, f * ny + j, closed, dx)
    for i in range(nx):
        for f in range(ny + 1):
            wall = f == 0 or f == ny
            closed = wall or solid[i, f - 1] or solid[i, f]
            face(i * ny + f - 1, i * ny + f, closed, dy)
    return np.array(rows), np.array(weights)


def project(ux, uy, G, w, shape):
    """``(ux', uy', p)``: ``p = A⁺ Gᵀ u`` (``A = GᵀG``; the pseudo-inverse
    gives the solution of zero mean over the active cells and zero in the
    obstacle), ``u' = W u - G p``."""
    nx, ny = shape
    u = jnp.concatenate([ux.ravel(), uy.ravel()])
    A = G.T @ G
    p = jnp.linalg.pinv(A, hermitian=True) @ (G.T @ u)
    v = w * u - G @ p
    k = (nx + 1) * ny
    return v[:k].reshape(nx + 1, ny), v[k:].reshape(nx, ny + 1), p.reshape(nx, ny)


def semi_lagrangian2(d, u, dt, spacing=(1.0, 1.0)):
    """Periodic semi-Lagrangian step: bilinear interpolation at the departure
    point ``(i - u_x dt/dx, j - u_y dt/dy)``."""
    nx, ny = d.shape
    i, j = jnp.meshgrid(jnp.arange(nx), jnp.arange(ny), indexing="ij")
    sx = i - u[0] * dt / spacing[0]
    sy = j - u[1] * dt / spacing[1]
    x0, y0 = jnp.floor(sx), jnp.floor(sy)
    fx, fy = sx - x0, sy - y0
    x0, y0 = x0.astype(int), y0.astype(int)

    def at(a, b):
        return d[a % nx, b % ny]

    return (1 - fx) * ((1 - fy) * at(x0, y0) + fy * at(x0, y0 + 1)) + fx * (
        (1 - fy) * at(x0 + 1, y0) + fy * at(x0 + 1, y0 + 1)
    )


def upwind2(d, u, dt, spacing=(1.0, 1.0)):
    """Periodic first-order upwind step, unsplit:
    ``d' = d - dt Σ_axes [min(u/h, 0) (d_{i+1} - d_i) + max(u/h, 0) (d_i - d_{i-1})]``."""
    out = d
    for axis, h in enumerate(spacing):
        a = u[axis] / h
        fwd = jnp.roll(d, -1, axis=axis) - d
        bwd = d - jnp.roll(d, 1, axis=axis)
        out = out - dt * (jnp.minimum(a, 0.0) * fwd + jnp.maximum(a, 0.0) * bwd)
    return out
