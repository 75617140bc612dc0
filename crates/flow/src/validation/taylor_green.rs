//! Analytic flows the step is checked against.
//!
//! **Taylor–Green vortex** in the periodic box `[0, 2π]²`, an exact solution
//! of the incompressible Navier–Stokes equations (density 1):
//!
//! ```text
//! u_x =  A sin x cos y · e^{−2νt}
//! u_y = −A cos x sin y · e^{−2νt}
//! P   =  A²/4 (cos 2x + cos 2y) · e^{−4νt}
//! ```
//!
//! The order study ([`TaylorGreen::order_study`]) runs it at amplitude 1,
//! ν = 0.01 to t = π/2 with dt = h/2 on several grids and reports the relative
//! max velocity error and the observed orders; its floor is the scheme's
//! formal order less a margin ([`OrderStudy::floor`]).
//!
//! # References
//! G. I. Taylor and A. E. Green, *Mechanism of the production of small eddies
//! from large ones*, Proc. R. Soc. Lond. A 158 (1937) 499–521.

use std::f64::consts::PI;

use diffphys_tape::Real;
use ndarray::Array2;

use crate::advection::Advection;
use crate::boundaries::Sides;
use crate::grid::Lattice;
use crate::pressure::PressureSolver;
use crate::{FlowError, FlowState, Result, Scene, SceneBuilder};

use super::FloorCheck;

/// The Taylor–Green vortex of amplitude `amplitude` and viscosity `viscosity`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaylorGreen {
    /// `A`.
    pub amplitude: f64,
    /// `ν`.
    pub viscosity: f64,
}

impl TaylorGreen {
    /// A builder for the periodic box `[0, 2π]²` with `n × n` cells, this
    /// viscosity, time step `dt` and scheme `advection`; the pressure is
    /// solved by the Fourier transform ([`PressureSolver::Fourier`]).
    pub fn scene(&self, n: usize, dt: f64, advection: Advection) -> SceneBuilder {
        Scene::builder(n, n, [2.0 * PI, 2.0 * PI])
            .sides(Sides::periodic())
            .viscosity(self.viscosity)
            .dt(dt)
            .advection(advection)
            .pressure_solver(PressureSolver::Fourier)
    }

    /// `e^{−2νt}`.
    pub fn decay(&self, t: f64) -> f64 {
        (-2.0 * self.viscosity * t).exp()
    }

    /// The exact state at time `t` on the scene's faces and cells.
    pub fn state<T: Real>(&self, scene: &Scene, t: f64) -> FlowState<T> {
        let g = scene.grid();
        let (a, d) = (self.amplitude, self.decay(t));
        let on = |lat: Lattice, f: &dyn Fn(f64, f64) -> f64| {
            let [na, nb] = g.shape(lat);
            Array2::from_shape_fn((na, nb), |(i, j)| {
                let [x, y] = g.position(lat, i, j);
                T::from_f64(f(x, y))
            })
        };
        let mut s = FlowState::zeros(scene);
        s.ux = on(Lattice::FaceX, &|x, y| a * x.sin() * y.cos() * d);
        s.uy = on(Lattice::FaceY, &|x, y| -a * x.cos() * y.sin() * d);
        s.pressure = on(Lattice::Cell, &|x, y| {
            a * a / 4.0 * ((2.0 * x).cos() + (2.0 * y).cos()) * d * d
        });
        s
    }

    /// The largest velocity error of `state` against the exact solution at
    /// time `t`, relative to the exact amplitude `A e^{−2νt}`.
    pub fn velocity_error<T: Real>(&self, scene: &Scene, state: &FlowState<T>, t: f64) -> f64 {
        let exact = self.state::<f64>(scene, t);
        let err = |a: &Array2<T>, b: &Array2<f64>| {
            a.iter()
                .zip(b)
                .fold(0.0f64, |m, (p, q)| m.max((p.as_f64() - q).abs()))
        };
        err(&state.ux, &exact.ux).max(err(&state.uy, &exact.uy)) / (self.amplitude * self.decay(t))
    }

    /// Runs the vortex on `scene` from the exact state at 0 for `steps`
    /// steps without a tape and returns the relative velocity error then.
    ///
    /// # Errors
    /// As [`Scene::forward`].
    pub fn run(&self, scene: &Scene, steps: usize) -> Result<f64> {
        let mut s = self.state::<f64>(scene, 0.0);
        let mut p = scene.params::<f64>();
        p.viscosity = self.viscosity;
        for _ in 0..steps {
            s = scene.forward(&s, &p)?.0;
        }
        Ok(self.velocity_error(scene, &s, steps as f64 * scene.dt()))
    }
}

/// The Taylor–Green error on several grids and the observed orders.
#[derive(Debug, Clone, PartialEq)]
pub struct OrderStudy {
    /// The advection scheme.
    pub advection: Advection,
    /// Cells per side of each grid, ascending.
    pub grids: Vec<usize>,
    /// The relative max velocity error at t = π/2 on each grid.
    pub errors: Vec<f64>,
    /// `log2`-style observed orders between successive grids,
    /// `ln(e_k / e_{k+1}) / ln(n_{k+1} / n_k)`.
    pub orders: Vec<f64>,
}

impl TaylorGreen {
    /// The vortex of the order study: amplitude 1, ν = 0.01.
    pub const STUDY: TaylorGreen = TaylorGreen {
        amplitude: 1.0,
        viscosity: 0.01,
    };

    /// The relative max velocity error on `n × n` cells at t = π/2 with
    /// dt = h/2 (`n / 2` steps).
    ///
    /// # Errors
    /// [`FlowError::InvalidParameter`] for an odd `n` or one below 4; those
    /// of [`Scene::forward`].
    pub fn error_at(&self, n: usize, advection: Advection) -> Result<f64> {
        if n < 4 || n % 2 != 0 {
            return Err(FlowError::parameter(
                "Taylor-Green",
                "n",
                format!("must be even and at least 4, got {n}"),
            ));
        }
        let dt = PI / n as f64; // h / 2
        let scene = self.scene(n, dt, advection).build()?;
        self.run(&scene, n / 2)
    }

    /// The errors on `grids` (ascending, at least two) and the observed orders.
    ///
    /// # Errors
    /// [`FlowError::InvalidParameter`] for fewer than two grids or grids not
    /// ascending; those of [`TaylorGreen::error_at`].
    pub fn order_study(&self, grids: &[usize], advection: Advection) -> Result<OrderStudy> {
        if grids.len() < 2 || grids.windows(2).any(|w| w[0] >= w[1]) {
            return Err(FlowError::parameter(
                "Taylor-Green",
                "grids",
                format!("at least two grids, ascending, got {grids:?}"),
            ));
        }
        let errors = grids
            .iter()
            .map(|&n| self.error_at(n, advection))
            .collect::<Result<Vec<f64>>>()?;
        let orders = super::observed_orders(grids, &errors)
            .into_iter()
            .map(|o| o.unwrap_or(f64::NAN))
            .collect();
        Ok(OrderStudy {
            advection,
            grids: grids.to_vec(),
            errors,
            orders,
        })
    }
}

impl OrderStudy {
    /// The least order the scheme must show: its formal order less a margin
    /// for the pre-asymptotic error: 1.8 for MacCormack without the limiter
    /// (second order), 1.4 with it (the limiter clips extrema to first order
    /// locally), 0.9 for semi-Lagrangian (first order with dt ∝ h).
    pub fn least_order(advection: Advection) -> f64 {
        match advection {
            Advection::MacCormack { limiter: false } => 1.8,
            Advection::MacCormack { limiter: true } => 1.4,
            Advection::SemiLagrangian => 0.9,
        }
    }

    /// The floor over the orders between the grids from `from` cells on: the
    /// smallest of them against [`OrderStudy::least_order`] (NaN, and so not
    /// met, where no pair of grids starts at `from` or above).
    pub fn floor(&self, from: usize) -> FloorCheck {
        let smallest = self
            .orders
            .iter()
            .zip(&self.grids)
            .filter(|(_, &n)| n >= from)
            .map(|(&o, _)| o)
            // a NaN order (an error that did not fall) is kept, not skipped
            .fold(None, |m: Option<f64>, o| {
                Some(m.map_or(o, |m| {
                    if o.is_nan() || m.is_nan() {
                        f64::NAN
                    } else {
                        m.min(o)
                    }
                }))
            })
            .unwrap_or(f64::NAN);
        FloorCheck::at_least(
            "smallest observed order",
            smallest,
            Self::least_order(self.advection),
            "the scheme's formal order less the pre-asymptotic margin",
        )
    }
}
