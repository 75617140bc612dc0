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
use crate::{FlowState, Result, Scene, SceneBuilder};

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
