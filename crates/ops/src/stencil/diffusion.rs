//! One explicit (forward Euler) diffusion step, `u + ν·dt·∇²u`.

use diffphys_tape::Real;
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD};

use super::laplacian::{five_point_operator, FivePoint};
use crate::{Grid1, Grid2, LinearOperator, OpsError, Result};

/// Viscosity and time step of an explicit diffusion step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiffusionParams {
    /// The diffusivity `ν ≥ 0`.
    pub nu: f64,
    /// The time step `dt > 0`.
    pub dt: f64,
    /// Accept a step above the stability limit `ν·dt·Σ 1/h² ≤ ½` (for stability
    /// studies); off by default.
    pub allow_unstable: bool,
}

impl DiffusionParams {
    /// Diffusivity `nu` and step `dt`, refusing unstable steps.
    pub fn new(nu: f64, dt: f64) -> Self {
        DiffusionParams {
            nu,
            dt,
            allow_unstable: false,
        }
    }

    /// Checks the parameters; `inv_h2` is `Σ 1/h²` over the axes.
    fn check(&self, op: &str, inv_h2: f64) -> Result<()> {
        if !(self.nu.is_finite() && self.nu >= 0.0 && self.dt.is_finite() && self.dt > 0.0) {
            return Err(OpsError::invalid(
                op,
                format!(
                    "need finite ν ≥ 0 and dt > 0, got ν = {}, dt = {}",
                    self.nu, self.dt
                ),
            ));
        }
        let number = self.nu * self.dt * inv_h2;
        if number > 0.5 && !self.allow_unstable {
            return Err(OpsError::invalid(
                op,
                format!(
                    "unstable explicit diffusion: ν·dt·Σ1/h² = {number:.4} exceeds 1/2; reduce dt or set allow_unstable"
                ),
            ));
        }
        Ok(())
    }
}

/// One explicit diffusion step on a [`Grid1`]: `A u = u + ν·dt·∇²u`, with the
/// Laplacian of [`super::Laplacian1`] (same ghost cells). Symmetric: `Aᵀ = A`.
/// Stable (and then a contraction in the 2-norm) for `ν·dt/dx² ≤ ½`.
///
/// # References
/// R. J. LeVeque, *Finite Difference Methods for Ordinary and Partial Differential
/// Equations*, SIAM 2007, §9.1 and §9.4 (stability of forward Euler).
#[derive(Debug, Clone, PartialEq)]
pub struct ExplicitDiffusion1 {
    grid: Grid1,
    params: DiffusionParams,
    shape: [usize; 1],
    stencil: FivePoint,
}

impl ExplicitDiffusion1 {
    /// The diffusion step on `grid`.
    ///
    /// # Errors
    /// [`OpsError::InvalidArgument`] for a negative or non-finite `ν`, a
    /// non-positive `dt`, or an unstable step not explicitly allowed.
    pub fn new(grid: Grid1, params: DiffusionParams) -> Result<Self> {
        params.check("explicit_diffusion_1d", 1.0 / (grid.dx * grid.dx))?;
        Ok(ExplicitDiffusion1 {
            grid,
            params,
            shape: grid.shape(),
            stencil: FivePoint::one_d(&grid, params.nu * params.dt, 1.0),
        })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid1 {
        &self.grid
    }

    /// The parameters.
    pub fn params(&self) -> &DiffusionParams {
        &self.params
    }
}

five_point_operator!(ExplicitDiffusion1, "explicit_diffusion_1d");

/// One explicit diffusion step on a [`Grid2`]: `A u = u + ν·dt·∇²u`, with the
/// Laplacian of [`super::Laplacian2`]. Symmetric: `Aᵀ = A`. Stable for
/// `ν·dt·(1/dx² + 1/dy²) ≤ ½`.
///
/// # References
/// R. J. LeVeque, *Finite Difference Methods for Ordinary and Partial Differential
/// Equations*, SIAM 2007, §9.1 and §9.4.
#[derive(Debug, Clone, PartialEq)]
pub struct ExplicitDiffusion2 {
    grid: Grid2,
    params: DiffusionParams,
    shape: [usize; 2],
    stencil: FivePoint,
}

impl ExplicitDiffusion2 {
    /// The diffusion step on `grid`.
    ///
    /// # Errors
    /// As [`ExplicitDiffusion1::new`].
    pub fn new(grid: Grid2, params: DiffusionParams) -> Result<Self> {
        let inv_h2 = 1.0 / (grid.dx * grid.dx) + 1.0 / (grid.dy * grid.dy);
        params.check("explicit_diffusion_2d", inv_h2)?;
        Ok(ExplicitDiffusion2 {
            grid,
            params,
            shape: grid.shape(),
            stencil: FivePoint::two_d(&grid, params.nu * params.dt, 1.0),
        })
    }

    /// The grid.
    pub fn grid(&self) -> &Grid2 {
        &self.grid
    }

    /// The parameters.
    pub fn params(&self) -> &DiffusionParams {
        &self.params
    }
}

five_point_operator!(ExplicitDiffusion2, "explicit_diffusion_2d");
