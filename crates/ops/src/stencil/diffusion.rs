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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stencil::{Laplacian1, Laplacian2};
    use crate::Boundary;
    use diffphys_tape::{check_adjoint, test_array};

    #[test]
    fn diffusion_is_identity_plus_scaled_laplacian() {
        for b in [
            Boundary::Periodic,
            Boundary::ZeroDirichlet,
            Boundary::Closed,
        ] {
            let g = Grid2::new(5, 4, 0.5, 0.25, b).unwrap();
            let p = DiffusionParams::new(0.01, 0.1);
            let a = ExplicitDiffusion2::new(g, p).unwrap();
            let x = test_array::<f64>(&[5, 4], 1);
            let lap = Laplacian2::new(g).scaled(0.001).apply(x.view()).unwrap();
            let ax = a.apply(x.view()).unwrap();
            for ((p, l), x) in ax.iter().zip(&lap).zip(&x) {
                assert!((p - (x + l)).abs() < 1e-14);
            }
            let y = test_array::<f64>(&[5, 4], 2);
            let rep = check_adjoint(
                |v| a.apply(v).unwrap(),
                |v| a.apply_transpose(v).unwrap(),
                x.view(),
                y.view(),
            )
            .unwrap();
            assert!(rep.passes(1e-14));
            let d: ArrayD<f64> = a.diagonal().unwrap();
            // 1 − 2ν·dt·(1/dx² + 1/dy²) = 1 − 0.002·(4 + 16) = 0.96 inside
            assert!((d[[2, 2]] - 0.96).abs() < 1e-14);

            let g1 = Grid1::new(6, 0.5, 0.0, b).unwrap();
            let a1 = ExplicitDiffusion1::new(g1, p).unwrap();
            let x1 = test_array::<f64>(&[6], 3);
            let l1 = Laplacian1::new(g1).scaled(0.001).apply(x1.view()).unwrap();
            let a1x = a1.apply(x1.view()).unwrap();
            for ((p, l), x) in a1x.iter().zip(&l1).zip(&x1) {
                assert!((p - (x + l)).abs() < 1e-14);
            }
        }
    }

    #[test]
    fn unstable_steps_are_refused_unless_allowed() {
        let g = Grid1::new(8, 0.1, 0.0, Boundary::Periodic).unwrap();
        // ν·dt/dx² = 1·0.01/0.01 = 1 > ½
        let p = DiffusionParams::new(1.0, 0.01);
        assert!(matches!(
            ExplicitDiffusion1::new(g, p),
            Err(OpsError::InvalidArgument { .. })
        ));
        let allowed = DiffusionParams {
            allow_unstable: true,
            ..p
        };
        assert!(ExplicitDiffusion1::new(g, allowed).is_ok());
        assert!(ExplicitDiffusion1::new(g, DiffusionParams::new(-1.0, 0.01)).is_err());
        assert!(ExplicitDiffusion1::new(g, DiffusionParams::new(0.1, 0.0)).is_err());
    }
}
