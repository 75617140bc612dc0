//! The scene every method is measured on: a Poisson solve inside a loss.
//!
//! Given the right-hand side `b` (the leaf whose gradient we want), solve
//! `A p = b` with `A = −∇²` (a 5-point stencil, [`Laplacian2::negative`]) and
//! evaluate a loss of `p`:
//!
//! - tracking: `L = ½‖p − p*‖²`, so `∂L/∂p = p − p*` and `∂L/∂b = A⁻¹(p − p*)`;
//! - weighted: `L = Σ w⊙p`, so `∂L/∂p = w` and `∂L/∂b = A⁻¹ w`.
//!
//! (`A` is symmetric, so `A⁻ᵀ = A⁻¹`.) The data are fixed smooth functions of the
//! cell centres on `[0, 1]²`, so every run of every method sees the same problem.

use diffphys_ops::cg::NullSpace;
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::{Boundary, Grid2};
use diffphys_tape::{Real, Var};
use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::{CompareError, Result};

/// Which operator `A` the scene solves with: the conditioning axis of the study.
/// Serialised as its [`label`](OperatorKind::label) (`laplacian`, `aniso100`,
/// `neumann`), parsed back by [`OperatorKind::parse`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(into = "String", try_from = "String")]
#[non_exhaustive]
pub enum OperatorKind {
    /// `−∇²` on `n × n` square cells of `[0, 1]²`, zero Dirichlet walls: condition
    /// number about `4n²/π²`.
    Laplacian,
    /// `−∇²` with cells `ratio` times as long along y as along x in squared
    /// spacing (`dy² = ratio·dx²`, so the y coupling is `ratio` times weaker),
    /// closed walls on the x faces and zero Dirichlet on the y faces. The
    /// smallest eigenvalue comes from the weak y direction alone, so the
    /// condition number is about `ratio` times the plain Laplacian's.
    Anisotropic {
        /// `dy²/dx²`, above 1 for the weakly coupled y axis.
        ratio: f64,
    },
    /// `−∇²` on `n × n` square cells with closed walls on all four sides: the
    /// all-Neumann pressure system of a closed box. Singular (the constants are
    /// its kernel), so the scene's right-hand side is made compatible (zero
    /// mean, as the divergence of a velocity with zero normal flow at the walls
    /// is), the solution is the zero-mean one, and solvers are told the null
    /// space ([`OperatorKind::null_space`]).
    Neumann,
}

impl OperatorKind {
    /// A short label for tables and charts: `laplacian`, `aniso100`, `neumann`.
    pub fn label(&self) -> String {
        match self {
            OperatorKind::Laplacian => "laplacian".to_string(),
            OperatorKind::Anisotropic { ratio } => format!("aniso{ratio}"),
            OperatorKind::Neumann => "neumann".to_string(),
        }
    }

    /// The kernel of the operator that solvers must project out:
    /// [`NullSpace::Constant`] for [`OperatorKind::Neumann`], none otherwise.
    pub fn null_space(&self) -> NullSpace {
        match self {
            OperatorKind::Neumann => NullSpace::Constant,
            OperatorKind::Laplacian | OperatorKind::Anisotropic { .. } => NullSpace::None,
        }
    }

    /// Parses a [`OperatorKind::label`]: `laplacian`, `aniso<ratio>` or `neumann`.
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] for anything else.
    pub fn parse(s: &str) -> Result<Self> {
        if s == "laplacian" {
            return Ok(OperatorKind::Laplacian);
        }
        if s == "neumann" {
            return Ok(OperatorKind::Neumann);
        }
        if let Some(r) = s.strip_prefix("aniso") {
            if let Ok(ratio) = r.parse::<f64>() {
                if ratio.is_finite() && ratio >= 1.0 {
                    return Ok(OperatorKind::Anisotropic { ratio });
                }
            }
        }
        Err(CompareError::invalid(format!(
            "unknown operator '{s}': expected 'laplacian', 'neumann' or 'aniso<ratio ≥ 1>', \
             e.g. aniso100"
        )))
    }
}

impl std::fmt::Display for OperatorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.label())
    }
}

impl From<OperatorKind> for String {
    fn from(op: OperatorKind) -> String {
        op.label()
    }
}

impl TryFrom<String> for OperatorKind {
    type Error = CompareError;

    fn try_from(label: String) -> Result<Self> {
        OperatorKind::parse(&label)
    }
}

/// Which loss of `p` the scene differentiates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum LossKind {
    /// `½‖p − p*‖²`: the gradient depends on the forward solution.
    Tracking,
    /// `Σ w⊙p`: linear in `p`, so the gradient `A⁻¹ w` does not depend on `b`.
    Weighted,
}

/// Everything that defines a scene; the scalar type is chosen separately.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ProblemSpec {
    /// Cells per axis (the grid is `n × n`).
    pub n: usize,
    /// The operator.
    pub operator: OperatorKind,
    /// The loss.
    pub loss: LossKind,
}

impl ProblemSpec {
    /// The plain Laplacian with the tracking loss on an `n × n` grid.
    pub fn laplacian(n: usize) -> Self {
        ProblemSpec {
            n,
            operator: OperatorKind::Laplacian,
            loss: LossKind::Tracking,
        }
    }

    /// The same scene with another operator.
    pub fn with_operator(mut self, operator: OperatorKind) -> Self {
        self.operator = operator;
        self
    }

    /// The same scene with another loss.
    pub fn with_loss(mut self, loss: LossKind) -> Self {
        self.loss = loss;
        self
    }

    /// The grid of the scene.
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] if `n < 2` or an anisotropy ratio is
    /// below 1 or not finite.
    pub fn grid(&self) -> Result<Grid2> {
        if self.n < 2 {
            return Err(CompareError::invalid(format!(
                "grid size n = {} is too small (need n ≥ 2)",
                self.n
            )));
        }
        let h = 1.0 / self.n as f64;
        let grid = match self.operator {
            OperatorKind::Laplacian => Grid2::square(self.n, self.n, h, Boundary::ZeroDirichlet)?,
            OperatorKind::Anisotropic { ratio } => {
                if !(ratio.is_finite() && ratio >= 1.0) {
                    return Err(CompareError::invalid(format!(
                        "anisotropy ratio {ratio} must be finite and ≥ 1"
                    )));
                }
                Grid2::new(self.n, self.n, h, h * ratio.sqrt(), Boundary::ZeroDirichlet)?
                    .with_boundaries(Boundary::Closed, Boundary::ZeroDirichlet)
            }
            OperatorKind::Neumann => Grid2::square(self.n, self.n, h, Boundary::Closed)?,
        };
        Ok(grid)
    }
}

/// A scene in scalar type `T`: the operator and the data.
#[derive(Debug, Clone)]
pub struct Problem<T: Real> {
    /// What it was built from.
    pub spec: ProblemSpec,
    /// The grid.
    pub grid: Grid2,
    /// `A = −∇²` on the grid.
    pub operator: Laplacian2,
    /// The right-hand side, the leaf of the gradient.
    pub b: Array2<T>,
    /// `p*` for the tracking loss, `w` for the weighted loss.
    pub target: Array2<T>,
}

impl<T: Real> Problem<T> {
    /// Builds the scene of `spec` in precision `T` (the data are computed in
    /// `f64` and rounded, so the `f32` scene is the `f64` one rounded).
    ///
    /// # Errors
    /// As [`ProblemSpec::grid`].
    pub fn new(spec: ProblemSpec) -> Result<Self> {
        let grid = spec.grid()?;
        let n = spec.n;
        let centre = |i: usize| (i as f64 + 0.5) / n as f64;
        let gauss = |x: f64, y: f64, cx: f64, cy: f64, w: f64| {
            (-((x - cx).powi(2) + (y - cy).powi(2)) / w).exp()
        };
        let pi = std::f64::consts::PI;
        // A positive and a negative source and a smooth background: every mode of
        // the solve matters a little.
        let mut b = Array2::from_shape_fn((n, n), |(i, j)| {
            let (x, y) = (centre(i), centre(j));
            20.0 * gauss(x, y, 0.3, 0.6, 0.02) - 12.0 * gauss(x, y, 0.7, 0.3, 0.03)
                + 4.0 * (3.0 * pi * x).sin() * (pi * y).sin()
        });
        if spec.operator.null_space() == NullSpace::Constant {
            // A singular system is solvable only for b ⟂ kernel: remove the mean.
            let mean = b.mean().unwrap_or(0.0);
            b.mapv_inplace(|v| v - mean);
        }
        let b = b.mapv(T::from_f64);
        let target = Array2::from_shape_fn((n, n), |(i, j)| {
            let (x, y) = (centre(i), centre(j));
            let v = match spec.loss {
                LossKind::Tracking => 0.05 * (pi * x).sin() * (2.0 * pi * y).sin(),
                LossKind::Weighted => gauss(x, y, 0.5, 0.5, 0.05),
            };
            T::from_f64(v)
        });
        Ok(Problem {
            spec,
            grid,
            operator: Laplacian2::negative(grid),
            b,
            target,
        })
    }

    /// The loss at `p`, in `f64`.
    pub fn loss(&self, p: &Array2<T>) -> f64 {
        match self.spec.loss {
            LossKind::Tracking => {
                0.5 * p
                    .iter()
                    .zip(&self.target)
                    .map(|(&a, &t)| (a.as_f64() - t.as_f64()).powi(2))
                    .sum::<f64>()
            }
            LossKind::Weighted => p
                .iter()
                .zip(&self.target)
                .map(|(&a, &w)| a.as_f64() * w.as_f64())
                .sum(),
        }
    }

    /// The loss of `p` recorded on `p`'s tape (the same loss as
    /// [`Problem::loss`]), for the methods that backpropagate through it.
    ///
    /// # Errors
    /// Whatever the tape's ops return.
    pub(crate) fn recorded_loss<'t>(&self, p: Var<'t, T>) -> diffphys_tape::Result<Var<'t, T>> {
        let target = p.tape().constant(self.target.clone().into_dyn());
        match self.spec.loss {
            LossKind::Tracking => {
                let d = p.sub(target)?;
                d.dot(d)?.mul_scalar(T::from_f64(0.5))
            }
            LossKind::Weighted => p.dot(target),
        }
    }

    /// `∂L/∂p` at `p`: `p − p*` (tracking) or `w` (weighted).
    pub fn loss_gradient(&self, p: &Array2<T>) -> Array2<T> {
        match self.spec.loss {
            LossKind::Tracking => p - &self.target,
            LossKind::Weighted => self.target.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn operator_labels_round_trip() {
        for k in [
            OperatorKind::Laplacian,
            OperatorKind::Anisotropic { ratio: 100.0 },
            OperatorKind::Neumann,
        ] {
            assert_eq!(OperatorKind::parse(&k.label()).unwrap(), k);
        }
        assert!(OperatorKind::parse("aniso0.5").is_err());
        assert!(OperatorKind::parse("poisson").is_err());
    }

    #[test]
    fn f32_scene_is_the_f64_scene_rounded() {
        let a = Problem::<f64>::new(ProblemSpec::laplacian(8)).unwrap();
        let b = Problem::<f32>::new(ProblemSpec::laplacian(8)).unwrap();
        for (x, y) in a.b.iter().zip(&b.b) {
            assert_eq!(*x as f32, *y);
        }
        assert!(Problem::<f64>::new(ProblemSpec::laplacian(1)).is_err());
    }

    #[test]
    fn tracking_loss_and_its_gradient() {
        let p = Problem::<f64>::new(ProblemSpec::laplacian(4)).unwrap();
        let q = p.target.mapv(|t| t + 2.0);
        // L = ½ Σ 2² = 2 per cell, ∂L/∂p = p − p* = 2.
        assert!((p.loss(&q) - 2.0 * 16.0).abs() < 1e-12);
        assert!(p.loss_gradient(&q).iter().all(|&g| (g - 2.0).abs() < 1e-12));
    }
}
