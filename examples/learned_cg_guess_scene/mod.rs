//! The physics of `learned_cg_guess`: the distribution of right-hand sides, the
//! divergence of random band-limited velocities on a staggered grid.

use diffphys::learn::guess::GuessProblem;
use diffphys::learn::LearnError;
use diffphys::ops::cg::{conjugate_gradient, CgParams};
use diffphys::ops::stencil::Laplacian2;
use ndarray::Array2;
use ndarray::{ArrayD, IxDyn};
use rand::rngs::StdRng;
use rand::Rng;

/// `b = ∇·u` of a random band-limited `u` on `n × n` cells, `dx = 1/n`.
pub struct RhsDistribution {
    n: usize,
    /// `[2K, n + 1]` and `[2K, n]`: `cos(πk x)` then `sin(πk x)` at faces / centres.
    at_faces: Array2<f64>,
    at_centres: Array2<f64>,
}

impl RhsDistribution {
    pub fn new(n: usize, modes: usize) -> Self {
        let basis = |points: usize, offset: f64| {
            Array2::from_shape_fn((2 * modes, points), |(m, i)| {
                let phase =
                    std::f64::consts::PI * (m % modes + 1) as f64 * (i as f64 + offset) / n as f64;
                if m < modes {
                    phase.cos()
                } else {
                    phase.sin()
                }
            })
        };
        RhsDistribution {
            n,
            at_faces: basis(n + 1, 0.0),
            at_centres: basis(n, 0.5),
        }
    }

    fn component(rng: &mut StdRng, phi_x: &Array2<f64>, phi_y: &Array2<f64>) -> Array2<f64> {
        let m = phi_x.nrows();
        let c = Array2::from_shape_simple_fn((m, m), || rng.random_range(-1.0..1.0));
        phi_x.t().dot(&c).dot(phi_y)
    }

    /// One problem: `b` and its solution to relative residual 1e-10.
    pub fn draw(&self, lap: &Laplacian2, rng: &mut StdRng) -> Result<GuessProblem, LearnError> {
        let n = self.n;
        let u = Self::component(rng, &self.at_faces, &self.at_centres);
        let v = Self::component(rng, &self.at_centres, &self.at_faces);
        let b = ArrayD::from_shape_fn(IxDyn(&[n, n]), |ix| {
            let (i, j) = (ix[0], ix[1]);
            n as f64 * (u[[i + 1, j]] - u[[i, j]] + v[[i, j + 1]] - v[[i, j]])
        });
        let mut x = ArrayD::zeros(IxDyn(&[n, n]));
        conjugate_gradient(
            lap,
            b.view(),
            x.view_mut(),
            &CgParams::default().with_rel_tol(1e-10),
        )?;
        Ok(GuessProblem { b, x_star: x })
    }
}

pub fn rms(a: &ArrayD<f64>) -> f64 {
    (a.iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt()
}
