"""Type stubs of the extension module ``diffphys._native`` (built by maturin
from ``crates/python/src``). The docstrings live in the Rust doc comments;
``help(diffphys.Poisson)`` shows them."""

from typing import Literal, TypeAlias, TypeVar, final, overload

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "DiffphysError",
    "FlowStep",
    "InvalidArgumentError",
    "NonFiniteError",
    "NotConvergedError",
    "Poisson",
    "Projection",
    "ShapeError",
    "UnstableError",
    "semi_lagrangian2",
    "semi_lagrangian2_vjp",
    "upwind2",
    "upwind2_vjp",
]

# Every operator takes float32 or float64 arrays and answers in the same dtype.
_Float = TypeVar("_Float", np.float32, np.float64)
_BoolArray: TypeAlias = NDArray[np.bool_]

_BoundaryName: TypeAlias = Literal[
    "dirichlet", "zero_dirichlet", "closed", "neumann", "wall", "periodic"
]
_Boundary: TypeAlias = _BoundaryName | tuple[_BoundaryName, _BoundaryName]
_Preconditioner: TypeAlias = Literal["multigrid", "mg", "jacobi", "none", "cg"]
_SideName: TypeAlias = Literal["no_slip", "wall", "free_slip", "periodic", "inflow", "outflow"]
_Side: TypeAlias = _SideName | tuple[Literal["moving", "moving_wall"], float]
_SidesPreset: TypeAlias = _SideName | Literal["channel", "cavity"]
_Sides: TypeAlias = _SidesPreset | dict[Literal["left", "right", "bottom", "top"], _Side]
_SolveInfo: TypeAlias = dict[str, int | float | bool]
"""``{"iterations": int, "relative_residual": float, "converged": bool}``."""

class DiffphysError(Exception): ...
class ShapeError(DiffphysError): ...
class InvalidArgumentError(DiffphysError): ...
class NonFiniteError(DiffphysError): ...
class NotConvergedError(DiffphysError): ...
class UnstableError(DiffphysError): ...

# The defaults shown as `...` are tuples and strings in a Rust enum: pyo3 cannot
# print them (the class docstrings give them).

@final
class Poisson:
    def __new__(
        cls,
        shape: tuple[int, int],
        *,
        spacing: tuple[float, float] = ...,
        boundary: _Boundary = ...,
        preconditioner: _Preconditioner = "multigrid",
        rel_tol: float | None = None,
        abs_tol: float = 0.0,
        max_iters: int | None = None,
        sweeps: int = 2,
        adjoint_rel_tol: float | None = None,
        iterations: int | None = None,
    ) -> Poisson: ...
    @property
    def shape(self) -> tuple[int, int]: ...
    @overload
    def solve(
        self, b: NDArray[_Float], *, return_info: Literal[False] = False
    ) -> NDArray[_Float]: ...
    @overload
    def solve(
        self, b: NDArray[_Float], *, return_info: Literal[True]
    ) -> tuple[NDArray[_Float], _SolveInfo]: ...
    @overload
    def vjp(
        self, grad_p: NDArray[_Float], *, return_info: Literal[False] = False
    ) -> NDArray[_Float]: ...
    @overload
    def vjp(
        self, grad_p: NDArray[_Float], *, return_info: Literal[True]
    ) -> tuple[NDArray[_Float], _SolveInfo]: ...

@final
class Projection:
    def __new__(
        cls,
        shape: tuple[int, int],
        *,
        spacing: tuple[float, float] = ...,
        boundary: _Boundary = ...,
        obstacle: _BoolArray | None = None,
        preconditioner: _Preconditioner = "multigrid",
        rel_tol: float | None = None,
        abs_tol: float = 0.0,
        max_iters: int | None = None,
        sweeps: int = 2,
        adjoint_rel_tol: float | None = None,
        iterations: int | None = None,
    ) -> Projection: ...
    @property
    def shape(self) -> tuple[int, int]: ...
    @property
    def shape_x(self) -> tuple[int, int]: ...
    @property
    def shape_y(self) -> tuple[int, int]: ...
    @overload
    def project(
        self, ux: NDArray[_Float], uy: NDArray[_Float], *, return_info: Literal[False] = False
    ) -> tuple[NDArray[_Float], NDArray[_Float], NDArray[_Float]]: ...
    @overload
    def project(
        self, ux: NDArray[_Float], uy: NDArray[_Float], *, return_info: Literal[True]
    ) -> tuple[NDArray[_Float], NDArray[_Float], NDArray[_Float], _SolveInfo]: ...
    def vjp(
        self,
        grad_ux: NDArray[_Float] | None = None,
        grad_uy: NDArray[_Float] | None = None,
        grad_p: NDArray[_Float] | None = None,
    ) -> tuple[NDArray[_Float], NDArray[_Float]]: ...

@final
class FlowStep:
    def __new__(
        cls,
        shape: tuple[int, int],
        size: tuple[float, float],
        *,
        sides: _Sides | None = None,
        obstacle: _BoolArray | None = None,
        viscosity: float = 0.01,
        dt: float = 0.01,
        inflow: float | list[float] | NDArray[np.float64] | None = None,
        advection: Literal["semi_lagrangian", "maccormack"] = "semi_lagrangian",
        viscosity_mode: Literal["explicit", "implicit"] = "explicit",
        pressure_solver: Literal["cholesky", "fourier", "cg", "multigrid"] = "cholesky",
        pressure_rel_tol: float = 1e-10,
        splitting: Literal["incremental", "plain"] = "incremental",
        substepping: bool = False,
        max_courant: float = 1.0,
        buffer_limit_bytes: int = ...,
        immersed: tuple[float, float, float] | None = None,
        immersed_interior: Literal["solid", "forced"] = "solid",
        immersed_scheme: Literal["direct", "consistent"] = "direct",
    ) -> FlowStep: ...
    @property
    def held_bytes(self) -> int: ...
    def release_buffers(self) -> None: ...
    @property
    def shape(self) -> tuple[int, int]: ...
    @property
    def shape_x(self) -> tuple[int, int]: ...
    @property
    def shape_y(self) -> tuple[int, int]: ...
    @property
    def dt(self) -> float: ...
    @property
    def viscosity(self) -> float: ...
    @property
    def inflow_len(self) -> int: ...
    @property
    def solid(self) -> _BoolArray: ...
    def forward(
        self,
        ux: NDArray[_Float],
        uy: NDArray[_Float],
        *,
        steps: int = 1,
        pressure: NDArray[_Float] | None = None,
        viscosity: float | None = None,
        wall_speed: NDArray[_Float] | None = None,
        inflow: NDArray[_Float] | None = None,
    ) -> tuple[NDArray[_Float], NDArray[_Float], NDArray[_Float], NDArray[_Float]]: ...
    def vjp(
        self,
        ux: NDArray[_Float],
        uy: NDArray[_Float],
        grad_ux: NDArray[_Float] | None = None,
        grad_uy: NDArray[_Float] | None = None,
        grad_pressure: NDArray[_Float] | None = None,
        grad_force: NDArray[_Float] | None = None,
        *,
        steps: int = 1,
        pressure: NDArray[_Float] | None = None,
        viscosity: float | None = None,
        wall_speed: NDArray[_Float] | None = None,
        inflow: NDArray[_Float] | None = None,
        checkpoint_every: int | None = None,
    ) -> tuple[
        NDArray[_Float], NDArray[_Float], NDArray[_Float], float, NDArray[_Float], NDArray[_Float]
    ]: ...

def semi_lagrangian2(
    d: NDArray[_Float],
    u: NDArray[_Float],
    *,
    dt: float,
    spacing: tuple[float, float] = ...,
    boundary: _Boundary = ...,
) -> NDArray[_Float]: ...
def semi_lagrangian2_vjp(
    d: NDArray[_Float],
    u: NDArray[_Float],
    grad_out: NDArray[_Float],
    *,
    dt: float,
    spacing: tuple[float, float] = ...,
    boundary: _Boundary = ...,
) -> tuple[NDArray[_Float], NDArray[_Float]]: ...
def upwind2(
    d: NDArray[_Float],
    u: NDArray[_Float],
    *,
    dt: float,
    spacing: tuple[float, float] = ...,
    boundary: _Boundary = ...,
    allow_cfl_violation: bool = False,
) -> NDArray[_Float]: ...
def upwind2_vjp(
    d: NDArray[_Float],
    u: NDArray[_Float],
    grad_out: NDArray[_Float],
    *,
    dt: float,
    spacing: tuple[float, float] = ...,
    boundary: _Boundary = ...,
    allow_cfl_violation: bool = False,
) -> tuple[NDArray[_Float], NDArray[_Float]]: ...
