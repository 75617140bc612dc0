"""Each failure arrives as the exception class of its kind, with the Rust
message."""

import numpy as np
import pytest

import diffphys as dp


def test_bad_shape():
    with pytest.raises(dp.ShapeError, match="shape"):
        dp.Poisson((8, 8)).solve(np.zeros((8, 9)))
    with pytest.raises(dp.ShapeError, match=r"\[2, 6, 5\]"):
        dp.upwind2(np.zeros((6, 5)), np.zeros((2, 5, 6)), dt=0.1)
    proj = dp.Projection((6, 5))
    with pytest.raises(dp.ShapeError, match="ux"):
        proj.project(np.zeros((6, 5)), np.zeros(proj.shape_y))


def test_nan_input():
    b = np.ones((8, 8))
    b[3, 4] = np.nan
    with pytest.raises(dp.NonFiniteError, match="non-finite"):
        dp.poisson_solve(b)
    u = np.zeros((2, 8, 8))
    u[0, 1, 1] = np.inf
    with pytest.raises(dp.NonFiniteError):
        dp.semi_lagrangian2(np.ones((8, 8)), u, dt=0.1)


def test_unconverged_solve():
    b = np.random.default_rng(0).standard_normal((32, 32))
    with pytest.raises(dp.NotConvergedError, match="did not converge in 3 iterations"):
        dp.poisson_solve(b, preconditioner="none", max_iters=3)


def test_below_rounding_floor_is_not_converged():
    b = np.random.default_rng(0).standard_normal((32, 32)).astype(np.float32)
    with pytest.raises(dp.NotConvergedError, match="rounding floor"):
        dp.poisson_solve(b, rel_tol=1e-12)


def test_cfl_violation_is_unstable():
    u = np.full((2, 8, 8), 20.0)
    with pytest.raises(dp.UnstableError, match="CFL"):
        dp.upwind2(np.ones((8, 8)), u, dt=0.1)
    dp.upwind2(np.ones((8, 8)), u, dt=0.1, allow_cfl_violation=True)


def test_invalid_arguments():
    with pytest.raises(dp.InvalidArgumentError, match="boundary"):
        dp.Poisson((8, 8), boundary="sticky")
    with pytest.raises(dp.InvalidArgumentError, match="preconditioner"):
        dp.Poisson((8, 8), preconditioner="ilu")
    with pytest.raises(dp.InvalidArgumentError, match="rel_tol"):
        dp.Poisson((8, 8), rel_tol=-1.0)


def test_dtype_errors_are_type_errors():
    with pytest.raises(TypeError, match="float32 or float64"):
        dp.poisson_solve(np.zeros((8, 8), dtype=np.int64))
    with pytest.raises(TypeError, match="float64"):
        dp.upwind2(np.zeros((4, 4)), np.zeros((2, 4, 4), np.float32), dt=0.1)


def test_every_error_is_a_diffphys_error():
    for cls in (dp.ShapeError, dp.NonFiniteError, dp.NotConvergedError, dp.UnstableError,
                dp.InvalidArgumentError):
        assert issubclass(cls, dp.DiffphysError)
