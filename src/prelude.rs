//! Everything the tutorials use, in one import: `use diffphys::prelude::*;`.
//!
//! The tape and its checks, the grids, stencils, advection schemes, solves and
//! projection of `ops`, the layers of `nn`, and the `ndarray` and `rand` names
//! a first program needs. Modules ([`crate::ops`], [`crate::flow`],
//! [`crate::learn`], …) hold the rest.

pub use diffphys_tape::{
    check_adjoint, check_gradient, checkpointed_steps, test_array, Adam, BackwardArgs,
    GradCheckOptions, GradientDescent, Gradients, Op, Optimizer, Real, Schedule, Tape, TapeError,
    TapeStats, Var,
};

pub use diffphys_ops::advection::{SemiLagrangian1, SemiLagrangian2, Upwind1, Upwind2};
pub use diffphys_ops::cg::{conjugate_gradient, CgError, CgInfo, CgParams};
pub use diffphys_ops::mac::MacGrid;
pub use diffphys_ops::poisson::PoissonSolve;
pub use diffphys_ops::projection::{PressureProjection, ProjectionOp};
pub use diffphys_ops::stencil::{
    Divergence1, Divergence2, Gradient1, Gradient2, Laplacian1, Laplacian2,
};
pub use diffphys_ops::tape_ops::LinearOp;
pub use diffphys_ops::{Boundary, CellMask, Grid1, Grid2, LinearOperator, OpsError};

pub use diffphys_nn::{
    Activation, Conv1, Conv2, ConvConfig, Dense, Init, Layer, Mlp, NnError, Padding, Params,
    Sequential, UNet, UNetConfig,
};

pub use ndarray::{
    array, s, Array, Array1, Array2, Array3, ArrayD, ArrayView1, ArrayView2, ArrayViewD, Axis,
    IxDyn, Zip,
};
pub use rand::{rngs::StdRng, SeedableRng};
