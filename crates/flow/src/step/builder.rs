//! The numerical settings of a scene and its builder, which checks the
//! description and assembles the operators once.

use std::sync::Arc;

use diffphys_ops::cg::CgParams;
use diffphys_tape::pool::BufferPool;
use ndarray::{Array1, Array2};

use super::{Scene, SceneInner};
use crate::advection::Advection;
use crate::boundaries::{inflow_side, Faces, Obstacle};
use crate::diagnostics::ForceWeights;
use crate::diffusion::{default_viscosity_solver, Diffusion, ViscosityMode};
use crate::forcing::{Buoyancy, Forcing};
use crate::grid::FlowGrid;
use crate::immersed::{Circle, ForcingScheme, ImmersedCircle, Interior};
use crate::pressure::{PressureSolver, PressureSystem};
use crate::sides::{check_condition, Boundary, Side, Sides};
use crate::spectral::PeriodicPoisson;
use crate::{FlowError, Result};

/// How the pressure enters the step (see the [module docs](super)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Splitting {
    /// Advect, diffuse, project: `P = p/dt`.
    Plain,
    /// Advect `u − (dt/2)∇P`, project with `τ = dt/2` (second order).
    Incremental,
}

/// The numerical choices of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// The advection scheme (default semi-Lagrangian).
    pub advection: Advection,
    /// Explicit or implicit viscosity (default explicit).
    pub viscosity_mode: ViscosityMode,
    /// The pressure solver (default sparse Cholesky).
    pub pressure_solver: PressureSolver,
    /// How the pressure enters the step (default incremental).
    pub splitting: Splitting,
    /// The largest Courant number `max |u| dt/h` a step may take (default 1).
    pub max_courant: f64,
    /// Take as many substeps as the CFL limits need instead of failing
    /// (default off).
    pub substepping: bool,
    /// The implicit viscosity solve (CG, Jacobi, relative tolerance 1e-10).
    pub viscosity_solver: CgParams,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            advection: Advection::SemiLagrangian,
            viscosity_mode: ViscosityMode::Explicit,
            pressure_solver: PressureSolver::Cholesky,
            splitting: Splitting::Incremental,
            max_courant: 1.0,
            substepping: false,
            viscosity_solver: default_viscosity_solver(),
        }
    }
}

impl Scene {
    /// A scene of `nx × ny` cells over the domain `[0, size[0]] × [0, size[1]]`.
    pub fn builder(nx: usize, ny: usize, size: [f64; 2]) -> SceneBuilder {
        SceneBuilder {
            nx,
            ny,
            size,
            sides: Sides::all(Boundary::no_slip()),
            obstacle: Obstacle::None,
            viscosity: 0.01,
            dt: 0.01,
            inflow: None,
            buoyancy: None,
            forcing: None,
            immersed: None,
            interior: Interior::Solid,
            scheme: ForcingScheme::Direct,
            scalars: 0,
            settings: Settings::default(),
        }
    }
}

/// Builds a [`Scene`]; every choice has a default but the resolution and the
/// domain size.
#[derive(Debug, Clone)]
pub struct SceneBuilder {
    nx: usize,
    ny: usize,
    size: [f64; 2],
    sides: Sides,
    obstacle: Obstacle,
    viscosity: f64,
    dt: f64,
    inflow: Option<Vec<f64>>,
    buoyancy: Option<Buoyancy>,
    forcing: Option<Arc<dyn Forcing>>,
    immersed: Option<Circle>,
    interior: Interior,
    scheme: ForcingScheme,
    scalars: usize,
    settings: Settings,
}

impl SceneBuilder {
    /// The four side conditions (default: no-slip walls).
    pub fn sides(mut self, sides: Sides) -> Self {
        self.sides = sides;
        self
    }

    /// The obstacle (default none).
    pub fn obstacle(mut self, obstacle: Obstacle) -> Self {
        self.obstacle = obstacle;
        self
    }

    /// The obstacle as an immersed circle ([`crate::immersed`]): the cells
    /// of [`Obstacle::cylinder`] of the same circle stay solid (by default;
    /// see [`SceneBuilder::immersed_interior`]), and the free faces next to
    /// them are forced by interpolation to the true wall after the
    /// viscosity, before the projection. Replaces [`SceneBuilder::obstacle`].
    pub fn immersed(mut self, circle: Circle) -> Self {
        self.immersed = Some(circle);
        self
    }

    /// What lies inside the immersed circle (default [`Interior::Solid`]):
    /// with [`Interior::Forced`] no cell is solid, the faces inside the
    /// circle are forced to zero and the pressure spans the body; with
    /// [`Interior::Closed`] those faces are also closed in the pressure
    /// operator. Without [`SceneBuilder::immersed`] it does nothing.
    pub fn immersed_interior(mut self, interior: Interior) -> Self {
        self.interior = interior;
        self
    }

    /// How the immersed circle's forced faces are set (default
    /// [`ForcingScheme::Direct`]): [`ForcingScheme::ProjectionConsistent`]
    /// forces `F(u − τ∇Pⁿ) + τ∇Pⁿ` so that the projection leaves them on the
    /// interpolation ([`crate::immersed::consistent_forcing`]);
    /// [`ForcingScheme::MultiDirect`] alternates the direct forcing and the
    /// projection `passes` times within the step
    /// ([`crate::immersed::multi_direct_forcing`]), so that the steady state
    /// does not depend on the time step through the projection's slip.
    /// Without [`SceneBuilder::immersed`] it does nothing.
    pub fn immersed_scheme(mut self, scheme: ForcingScheme) -> Self {
        self.scheme = scheme;
        self
    }

    /// The kinematic viscosity `ν` (default 0.01), the default of
    /// [`super::FlowParams::viscosity`].
    pub fn viscosity(mut self, nu: f64) -> Self {
        self.viscosity = nu;
        self
    }

    /// The time step (default 0.01).
    pub fn dt(mut self, dt: f64) -> Self {
        self.dt = dt;
        self
    }

    /// The inflow profile: the normal velocity on the faces of the inflow
    /// side, one value per cell along it (`u_x` on the left or right, `u_y`
    /// at the bottom or top); the default of [`super::FlowParams::inflow`].
    pub fn inflow(mut self, profile: Vec<f64>) -> Self {
        self.inflow = Some(profile);
        self
    }

    /// A uniform inflow of `speed`.
    pub fn uniform_inflow(self, speed: f64) -> Self {
        let n = self.inflow_cells();
        self.inflow(vec![speed; n])
    }

    /// A parabolic (Poiseuille) inflow profile with `peak` at the middle of the
    /// side, zero at its ends.
    pub fn parabolic_inflow(self, peak: f64) -> Self {
        let n = self.inflow_cells();
        let profile = (0..n)
            .map(|j| {
                let s = (j as f64 + 0.5) / n as f64;
                4.0 * peak * s * (1.0 - s)
            })
            .collect();
        self.inflow(profile)
    }

    fn inflow_cells(&self) -> usize {
        match inflow_side(&self.sides) {
            Some(Side::Bottom | Side::Top) => self.nx,
            _ => self.ny,
        }
    }

    /// Passive scalars carried by the flow (default 0).
    pub fn scalars(mut self, n: usize) -> Self {
        self.scalars = n;
        self
    }

    /// A body force of the user's ([`Forcing`]), applied after advection on
    /// the free faces: the step records it as one op with its adjoint.
    pub fn forcing(mut self, forcing: Arc<dyn Forcing>) -> Self {
        self.forcing = Some(forcing);
        self
    }

    /// Boussinesq buoyancy of one of the scalars.
    pub fn buoyancy(mut self, buoyancy: Buoyancy) -> Self {
        self.buoyancy = Some(buoyancy);
        self
    }

    /// The advection scheme.
    pub fn advection(mut self, scheme: Advection) -> Self {
        self.settings.advection = scheme;
        self
    }

    /// Explicit or implicit viscosity.
    pub fn viscosity_mode(mut self, mode: ViscosityMode) -> Self {
        self.settings.viscosity_mode = mode;
        self
    }

    /// The pressure solver.
    pub fn pressure_solver(mut self, solver: PressureSolver) -> Self {
        self.settings.pressure_solver = solver;
        self
    }

    /// The splitting of pressure and advection.
    pub fn splitting(mut self, splitting: Splitting) -> Self {
        self.settings.splitting = splitting;
        self
    }

    /// The largest Courant number of a step.
    pub fn max_courant(mut self, limit: f64) -> Self {
        self.settings.max_courant = limit;
        self
    }

    /// Substep instead of failing on a CFL violation.
    pub fn substepping(mut self, on: bool) -> Self {
        self.settings.substepping = on;
        self
    }

    /// All numerical settings at once.
    pub fn settings(mut self, settings: Settings) -> Self {
        self.settings = settings;
        self
    }

    /// Checks the description and assembles the scene.
    ///
    /// # Errors
    /// [`FlowError::InvalidScene`] naming the quantity: a grid under 2 × 2
    /// cells, a size or `dt` not finite and positive, a viscosity ≤ 0, one
    /// periodic side without its opposite, more than one inflow side, an
    /// inflow without an outflow, a missing inflow profile or one of the wrong
    /// length, an obstacle that does not fit the grid or touches the inflow,
    /// a multi-direct forcing of no pass, buoyancy of a scalar that does not exist; solver errors of the
    /// factorisation.
    pub fn build(self) -> Result<Scene> {
        let SceneBuilder {
            nx,
            ny,
            size,
            sides,
            obstacle,
            viscosity,
            dt,
            inflow,
            buoyancy,
            forcing,
            immersed,
            interior,
            scheme,
            scalars,
            settings,
        } = self;
        let obstacle = immersed.map_or(obstacle, |c| Obstacle::cylinder(c.center, c.radius));
        if nx < 2 || ny < 2 {
            return Err(FlowError::scene(
                "resolution",
                format!("need at least 2 × 2 cells, got {nx} × {ny}"),
            ));
        }
        if !(size[0].is_finite() && size[0] > 0.0 && size[1].is_finite() && size[1] > 0.0) {
            return Err(FlowError::scene(
                "domain size",
                format!("need a finite size > 0, got {size:?}"),
            ));
        }
        if !(viscosity.is_finite() && viscosity > 0.0) {
            return Err(FlowError::scene(
                "viscosity",
                format!("need a finite viscosity > 0, got {viscosity}"),
            ));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(FlowError::scene(
                "dt",
                format!("need a finite time step > 0, got {dt}"),
            ));
        }
        if scheme == (ForcingScheme::MultiDirect { passes: 0 }) {
            return Err(FlowError::scene(
                "immersed scheme",
                "multi-direct forcing needs at least one pass, got 0",
            ));
        }
        if !(settings.max_courant.is_finite() && settings.max_courant > 0.0) {
            return Err(FlowError::scene(
                "max_courant",
                format!("need a finite limit > 0, got {}", settings.max_courant),
            ));
        }
        for (a, b, axis) in [
            (&sides.left, &sides.right, "x"),
            (&sides.bottom, &sides.top, "y"),
        ] {
            if a.is_periodic() != b.is_periodic() {
                return Err(FlowError::scene(
                    "sides",
                    format!("only one side along {axis} is periodic; both must be"),
                ));
            }
        }
        let cell = [size[0] / nx as f64, size[1] / ny as f64];
        for side in Side::ALL {
            let h = cell[usize::from(matches!(side, Side::Bottom | Side::Top))];
            check_condition(sides.get(side), &[h])
                .map_err(|e| FlowError::scene("sides", format!("the {side} side: {e}")))?;
        }
        let inflow_sides: Vec<Side> = Side::ALL
            .into_iter()
            .filter(|&s| sides.get(s).is_inflow())
            .collect();
        if inflow_sides.len() > 1 {
            return Err(FlowError::scene(
                "sides",
                format!(
                    "{} inflow sides; at most one is supported",
                    inflow_sides.len()
                ),
            ));
        }
        let has_outflow = Side::ALL.iter().any(|&s| sides.get(s).is_open());
        if !inflow_sides.is_empty() && !has_outflow {
            return Err(FlowError::scene(
                "sides",
                "an inflow needs an outflow side (the mass must leave)",
            ));
        }
        let inflow_side = inflow_sides.first().copied();
        let grid = FlowGrid {
            nx,
            ny,
            dx: size[0] / nx as f64,
            dy: size[1] / ny as f64,
            sides,
        };
        let inflow_len = match inflow_side {
            Some(Side::Left | Side::Right) => ny,
            Some(Side::Bottom | Side::Top) => nx,
            None => 0,
        };
        let inflow = match (inflow_side, inflow) {
            (None, _) => Array1::zeros(0),
            (Some(side), None) => {
                return Err(FlowError::scene(
                    "inflow profile",
                    format!("the {side} side is an inflow but no profile was given"),
                ));
            }
            (Some(side), Some(p)) => {
                if p.len() != inflow_len {
                    return Err(FlowError::scene(
                        "inflow profile",
                        format!("the {side} inflow needs {inflow_len} values (one per cell along it), got {}", p.len()),
                    ));
                }
                if p.iter().any(|v| !v.is_finite()) {
                    return Err(FlowError::scene("inflow profile", "holds NaN or infinity"));
                }
                Array1::from(p)
            }
        };
        let solid = obstacle.rasterise(&grid)?;
        if let Some(side) = inflow_side {
            let touching = (0..inflow_len).any(|k| match side {
                Side::Left => solid[[0, k]],
                Side::Right => solid[[nx - 1, k]],
                Side::Bottom => solid[[k, 0]],
                Side::Top => solid[[k, ny - 1]],
            });
            if touching {
                return Err(FlowError::scene(
                    "obstacle",
                    format!("the obstacle covers part of the {side} inflow side"),
                ));
            }
        }
        if solid.iter().all(|&s| s) {
            return Err(FlowError::scene(
                "obstacle",
                "the obstacle fills the whole domain",
            ));
        }
        // a forced interior: the circle's cells were rasterised for the checks
        // above, and are fluid
        let solid = match (immersed, interior) {
            (Some(_), Interior::Forced | Interior::Closed) => Array2::from_elem(solid.dim(), false),
            _ => solid,
        };
        if let Some(b) = buoyancy {
            if b.scalar >= scalars || !b.beta.is_finite() {
                return Err(FlowError::scene(
                    "buoyancy",
                    format!(
                        "scalar {} with β = {} (the scene has {scalars} scalars)",
                        b.scalar, b.beta
                    ),
                ));
            }
        }
        let faces = Arc::new(Faces::classify(&grid, &solid));
        // one set of Fourier solves for the viscosity and the pressure
        let spectral = PeriodicPoisson::for_grid(&grid, &faces).map(Arc::new);
        let diffusion = Diffusion::with_spectral(
            &grid,
            &faces,
            settings.viscosity_solver.clone(),
            spectral.clone(),
        );
        let immersed = immersed
            .map(|c| {
                let body = ImmersedCircle::new(&grid, &faces, &solid, c)?;
                Ok::<_, FlowError>(Arc::new(match interior {
                    Interior::Closed => body.closed(),
                    _ => body,
                }))
            })
            .transpose()?;
        // a closed interior: the forcing's zero faces are closed in the pressure
        let (pressure_faces, pressure_solid) = match (&immersed, interior) {
            (Some(body), Interior::Closed) => {
                let (f, s) = body.pressure_faces(&faces);
                (Arc::new(f), s)
            }
            _ => (Arc::clone(&faces), solid.clone()),
        };
        let pressure = PressureSystem::with_spectral(
            &grid,
            &pressure_faces,
            &pressure_solid,
            &settings.pressure_solver,
            spectral.as_ref(),
        )?;
        let forces = ForceWeights::new(&grid, &solid);
        Ok(Scene(Arc::new(SceneInner {
            grid,
            solid,
            faces,
            diffusion: Arc::new(diffusion),
            pressure: Arc::new(pressure),
            forces: Arc::new(forces),
            viscosity,
            dt,
            inflow,
            inflow_side,
            buoyancy,
            forcing,
            immersed,
            immersed_scheme: scheme,
            scalars,
            settings,
            buffers: BufferPool::new(),
        })))
    }
}
