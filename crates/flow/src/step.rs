//! The scene description and the step that composes the physics.
//!
//! A [`Scene`] is built once ([`Scene::builder`]): domain, resolution, sides,
//! obstacle, viscosity, time step, advection scheme, viscosity mode, pressure
//! solver. It assembles the stencils and factorises the pressure operator
//! then. The step is then
//!
//! ```text
//! u ← enforce_boundaries(u, inflow)             fixed faces from the sides and the obstacle
//! s ← advect_scalar(s; u)                        each passive scalar
//! u ← u − (dt/2) G P                             incremental splitting only
//! u ← advect_velocity(u; traced by uⁿ)           semi-Lagrangian or MacCormack
//! u ← u + dt β s̄ ŷ                               buoyancy, if any
//! u ← diffuse(u; ν)                               explicit or implicit
//! (u, P) ← project(u; guess P)                   τ = dt (plain) or dt/2 (incremental)
//! ```
//!
//! written once in `substep` over an [`Exec`]utor: on a tape every piece is
//! recorded as an op ([`Scene::step`]); without one the same ops' forwards run
//! directly and no tape memory is allocated ([`Scene::forward`]). On a scene
//! without a fixed face (a periodic box without obstacle) the first line is
//! the identity and is not run (nothing recorded for it).
//!
//! **Splitting.** [`Splitting::Plain`] is Chorin's projection: advect, diffuse,
//! project (`P = p/dt`); first order in time. [`Splitting::Incremental`] (the
//! default) advects `u − (dt/2)∇Pⁿ` and projects with `τ = dt/2`, so that
//! along a trajectory the pressure acts at the mid-point,
//! `uⁿ⁺¹ = uⁿ(X) − (dt/2)(∇Pⁿ(X) + ∇Pⁿ⁺¹)`: the splitting error of the plain
//! scheme (first order even with MacCormack) drops to second order. The
//! pressure of the state then matters to the next step and is differentiated
//! through; its use as the warm start of the pressure solve is not.
//!
//! **CFL.** The Courant number `max |u| dt/h` of the state (and, explicit,
//! the diffusion number `ν dt (1/dx² + 1/dy²)`) are checked before the step:
//! above [`Settings::max_courant`] (or ½) the step is [`FlowError::Cfl`] unless
//! [`Settings::substepping`] is on; then it takes `n` equal substeps, the least
//! that satisfy both, and reports `n` in [`StepInfo::substeps`].

use std::rc::Rc;
use std::sync::Arc;

use diffphys_ops::cg::CgParams;
use diffphys_tape::{
    checkpointed_steps, parallel, ArrayD, Op, Real, Schedule, StepFn, Tape, TapeError, Var,
};
use ndarray::{Array1, Array2, ArrayView2, Ix2, IxDyn};

use crate::advection::{AdvectScalar, AdvectVelocity, Advection};
use crate::boundaries::{inflow_side, EnforceBoundaries, Faces, Obstacle};
use crate::diagnostics::ForceWeights;
use crate::diffusion::{
    default_viscosity_solver, explicit_diffusion_number, Diffuse, Diffusion, ViscosityMode,
};
use crate::forcing::{Buoyancy, Buoyant};
use crate::grid::FlowGrid;
use crate::pressure::{
    PressureSolver, PressureSystem, Project, SolveCounter, SubtractPressureGradient,
};
use crate::sides::{Boundary, Side, Sides};
use crate::spectral::PeriodicPoisson;
use crate::{FlowError, Result};

/// How the pressure enters the step (see the [module docs](self)).
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

#[derive(Debug)]
struct SceneInner {
    grid: FlowGrid,
    solid: Array2<bool>,
    /// Which faces are fixed; with none (a periodic box without obstacle)
    /// enforcing the boundaries is the identity and skipped.
    faces: Arc<Faces>,
    diffusion: Arc<Diffusion>,
    pressure: Arc<PressureSystem>,
    forces: Arc<ForceWeights>,
    viscosity: f64,
    dt: f64,
    inflow: Array1<f64>,
    inflow_side: Option<Side>,
    buoyancy: Option<Buoyancy>,
    scalars: usize,
    settings: Settings,
}

/// A flow scene, built once by [`Scene::builder`]: the grid with its sides
/// and obstacle, the physical parameters, the numerical settings, and what
/// is assembled from them (stencils, the factorised pressure operator).
/// Cloning is cheap (shared).
#[derive(Debug, Clone)]
pub struct Scene(Arc<SceneInner>);

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

    /// The kinematic viscosity `ν` (default 0.01), the default of
    /// [`FlowParams::viscosity`].
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
    /// at the bottom or top); the default of [`FlowParams::inflow`].
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
    /// buoyancy of a scalar that does not exist; solver errors of the
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
            scalars,
            settings,
        } = self;
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
        if !(settings.max_courant.is_finite() && settings.max_courant > 0.0) {
            return Err(FlowError::scene(
                "max_courant",
                format!("need a finite limit > 0, got {}", settings.max_courant),
            ));
        }
        for (a, b, axis) in [
            (sides.left, sides.right, "x"),
            (sides.bottom, sides.top, "y"),
        ] {
            if a.is_periodic() != b.is_periodic() {
                return Err(FlowError::scene(
                    "sides",
                    format!("only one side along {axis} is periodic; both must be"),
                ));
            }
        }
        for side in Side::ALL {
            if let Boundary::MovingWall { speed } = sides.get(side) {
                if !speed.is_finite() {
                    return Err(FlowError::scene(
                        "wall speed",
                        format!("the {side} wall's speed is {speed}"),
                    ));
                }
            }
        }
        let inflow_sides: Vec<Side> = Side::ALL
            .into_iter()
            .filter(|&s| sides.get(s) == Boundary::Inflow)
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
        let has_outflow = Side::ALL.iter().any(|&s| sides.get(s) == Boundary::Outflow);
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
        let pressure = PressureSystem::with_spectral(
            &grid,
            &faces,
            &solid,
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
            scalars,
            settings,
        })))
    }
}

/// The state of a flow without a tape.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowState<T> {
    /// `u_x` on the x-faces ([`FlowGrid::shape_x`]).
    pub ux: Array2<T>,
    /// `u_y` on the y-faces ([`FlowGrid::shape_y`]).
    pub uy: Array2<T>,
    /// The pressure `P` at the cell centres (zero at rest; it warm-starts the
    /// next pressure solve, and with [`Splitting::Incremental`] enters the step).
    pub pressure: Array2<T>,
    /// Passive scalars at the cell centres.
    pub scalars: Vec<Array2<T>>,
}

impl<T: Real> FlowState<T> {
    /// The fluid at rest, scalars zero.
    pub fn zeros(scene: &Scene) -> Self {
        let g = scene.grid();
        let z = |s: [usize; 2]| Array2::zeros((s[0], s[1]));
        FlowState {
            ux: z(g.shape_x()),
            uy: z(g.shape_y()),
            pressure: z(g.cell_shape()),
            scalars: (0..scene.scalars()).map(|_| z(g.cell_shape())).collect(),
        }
    }

    /// A velocity, the pressure and scalars zero.
    pub fn from_velocity(scene: &Scene, ux: Array2<T>, uy: Array2<T>) -> Self {
        FlowState {
            ux,
            uy,
            ..Self::zeros(scene)
        }
    }
}

/// The state of a flow on a tape.
#[derive(Debug, Clone)]
pub struct FlowVars<'t, T: Real> {
    /// `u_x`.
    pub ux: Var<'t, T>,
    /// `u_y`.
    pub uy: Var<'t, T>,
    /// The pressure `P`.
    pub pressure: Var<'t, T>,
    /// Passive scalars.
    pub scalars: Vec<Var<'t, T>>,
}

impl<'t, T: Real> FlowVars<'t, T> {
    /// The state as constants on `tape`.
    pub fn constants(tape: &'t Tape<T>, s: &FlowState<T>) -> Self {
        FlowVars {
            ux: tape.constant(s.ux.clone().into_dyn()),
            uy: tape.constant(s.uy.clone().into_dyn()),
            pressure: tape.constant(s.pressure.clone().into_dyn()),
            scalars: s
                .scalars
                .iter()
                .map(|a| tape.constant(a.clone().into_dyn()))
                .collect(),
        }
    }

    /// The state with the velocity and scalars as variables (the pressure, a
    /// zero start or a warm start, as a constant).
    pub fn variables(tape: &'t Tape<T>, s: &FlowState<T>) -> Self {
        FlowVars {
            ux: tape.var(s.ux.clone().into_dyn()),
            uy: tape.var(s.uy.clone().into_dyn()),
            pressure: tape.constant(s.pressure.clone().into_dyn()),
            scalars: s
                .scalars
                .iter()
                .map(|a| tape.var(a.clone().into_dyn()))
                .collect(),
        }
    }

    /// `[u_x, u_y, P, scalars…]`, the layout of [`Scene::step_fn`].
    pub fn to_vec(&self) -> Vec<Var<'t, T>> {
        let mut v = vec![self.ux, self.uy, self.pressure];
        v.extend_from_slice(&self.scalars);
        v
    }

    /// From `[u_x, u_y, P, scalars…]`.
    ///
    /// # Errors
    /// [`FlowError::Shape`] for fewer than three entries.
    pub fn from_slice(v: &[Var<'t, T>]) -> Result<Self> {
        if v.len() < 3 {
            return Err(FlowError::shape(
                "flow step",
                "state list",
                &[3],
                &[v.len()],
            ));
        }
        Ok(FlowVars {
            ux: v[0],
            uy: v[1],
            pressure: v[2],
            scalars: v[3..].to_vec(),
        })
    }

    /// The values, copied off the tape.
    ///
    /// # Errors
    /// [`FlowError::Shape`] if a value is not 2D.
    pub fn values(&self) -> Result<FlowState<T>> {
        let two = |v: &Var<'t, T>, what: &str| -> Result<Array2<T>> {
            v.to_array()
                .into_dimensionality()
                .map_err(|_| FlowError::shape("flow step", what, &[0, 0], &v.shape()))
        };
        Ok(FlowState {
            ux: two(&self.ux, "x-velocity")?,
            uy: two(&self.uy, "y-velocity")?,
            pressure: two(&self.pressure, "pressure")?,
            scalars: self
                .scalars
                .iter()
                .map(|s| two(s, "scalar"))
                .collect::<Result<_>>()?,
        })
    }
}

/// The differentiable parameters of a step, without a tape.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowParams<T> {
    /// The kinematic viscosity `ν`.
    pub viscosity: T,
    /// The tangential speed of each side's wall, in the order of [`Side::ALL`]
    /// (read only on moving walls).
    pub wall_speed: Array1<T>,
    /// The inflow profile (empty without an inflow side).
    pub inflow: Array1<T>,
}

/// The differentiable parameters of a step on a tape: `ν` (0-d), the wall
/// speeds (`[4]`), the inflow profile.
#[derive(Debug, Clone, Copy)]
pub struct ParamVars<'t, T: Real> {
    /// `ν`.
    pub viscosity: Var<'t, T>,
    /// The four wall speeds.
    pub wall_speed: Var<'t, T>,
    /// The inflow profile.
    pub inflow: Var<'t, T>,
}

impl<'t, T: Real> ParamVars<'t, T> {
    /// The parameters as variables on `tape` (all of them get gradients).
    pub fn variables(tape: &'t Tape<T>, p: &FlowParams<T>) -> Self {
        ParamVars {
            viscosity: tape.var(ArrayD::from_elem(IxDyn(&[]), p.viscosity)),
            wall_speed: tape.var(p.wall_speed.clone().into_dyn()),
            inflow: tape.var(p.inflow.clone().into_dyn()),
        }
    }

    /// The parameters as constants on `tape`.
    pub fn constants(tape: &'t Tape<T>, p: &FlowParams<T>) -> Self {
        ParamVars {
            viscosity: tape.constant(ArrayD::from_elem(IxDyn(&[]), p.viscosity)),
            wall_speed: tape.constant(p.wall_speed.clone().into_dyn()),
            inflow: tape.constant(p.inflow.clone().into_dyn()),
        }
    }

    /// `[ν, wall_speed, inflow]`, the layout of [`Scene::step_fn`].
    pub fn to_vec(&self) -> Vec<Var<'t, T>> {
        vec![self.viscosity, self.wall_speed, self.inflow]
    }

    /// From `[ν, wall_speed, inflow]`.
    ///
    /// # Errors
    /// [`FlowError::Shape`] for a list of another length.
    pub fn from_slice(v: &[Var<'t, T>]) -> Result<Self> {
        if v.len() != 3 {
            return Err(FlowError::shape(
                "flow step",
                "parameter list",
                &[3],
                &[v.len()],
            ));
        }
        Ok(ParamVars {
            viscosity: v[0],
            wall_speed: v[1],
            inflow: v[2],
        })
    }
}

/// What a step did.
#[derive(Debug, Clone, PartialEq)]
pub struct StepInfo {
    /// Substeps taken (1 unless substepping was needed).
    pub substeps: usize,
    /// The Courant number `max |u| dt/h` of the state at the start, for the
    /// full `dt`.
    pub courant: f64,
    /// CG iterations of each pressure solve (0 for the direct solver).
    pub pressure_iterations: Vec<usize>,
}

impl Scene {
    /// A scene of `nx × ny` cells over the domain `[0, size[0]] × [0, size[1]]`.
    pub fn builder(nx: usize, ny: usize, size: [f64; 2]) -> SceneBuilder {
        SceneBuilder {
            nx,
            ny,
            size,
            sides: Sides::all(Boundary::NoSlip),
            obstacle: Obstacle::None,
            viscosity: 0.01,
            dt: 0.01,
            inflow: None,
            buoyancy: None,
            scalars: 0,
            settings: Settings::default(),
        }
    }

    /// The grid.
    pub fn grid(&self) -> &FlowGrid {
        &self.0.grid
    }

    /// The solid cells (`[nx, ny]`).
    pub fn solid(&self) -> &Array2<bool> {
        &self.0.solid
    }

    /// The time step.
    pub fn dt(&self) -> f64 {
        self.0.dt
    }

    /// The default viscosity.
    pub fn viscosity(&self) -> f64 {
        self.0.viscosity
    }

    /// The numerical settings.
    pub fn settings(&self) -> &Settings {
        &self.0.settings
    }

    /// Passive scalars in the state.
    pub fn scalars(&self) -> usize {
        self.0.scalars
    }

    /// The inflow side, if any.
    pub fn inflow_side(&self) -> Option<Side> {
        self.0.inflow_side
    }

    /// The length of the inflow profile (0 without an inflow side).
    pub fn inflow_len(&self) -> usize {
        self.0.inflow.len()
    }

    /// Whether the pressure operator is singular (no outflow side).
    pub fn pressure_is_singular(&self) -> bool {
        self.0.pressure.is_singular()
    }

    /// The condition on every face (the sides and the obstacle resolved):
    /// what [`crate::boundaries::enforce_boundaries`], the advection, the
    /// buoyancy and the pressure gradient take.
    pub fn faces(&self) -> &Arc<Faces> {
        &self.0.faces
    }

    /// The viscous operator, for [`crate::diffusion::diffuse`].
    pub fn diffusion(&self) -> &Arc<Diffusion> {
        &self.0.diffusion
    }

    /// The pressure system, for [`crate::pressure::project`].
    pub fn pressure_system(&self) -> &Arc<PressureSystem> {
        &self.0.pressure
    }

    /// The obstacle's surface, for [`crate::diagnostics::obstacle_force`].
    pub fn force_weights(&self) -> &Arc<ForceWeights> {
        &self.0.forces
    }

    /// The parameters the scene was built with (viscosity, wall speeds of its
    /// moving walls, inflow profile).
    pub fn params<T: Real>(&self) -> FlowParams<T> {
        let speed = |s: Side| match self.0.grid.sides.get(s) {
            Boundary::MovingWall { speed } => speed,
            _ => 0.0,
        };
        FlowParams {
            viscosity: T::from_f64(self.0.viscosity),
            wall_speed: Side::ALL.iter().map(|&s| T::from_f64(speed(s))).collect(),
            inflow: self.0.inflow.mapv(T::from_f64),
        }
    }

    /// `max |u_x| dt/dx + … `: the Courant number `max(|u_x|/dx, |u_y|/dy) · dt`.
    pub fn courant<T: Real>(&self, ux: ArrayView2<'_, T>, uy: ArrayView2<'_, T>, dt: f64) -> f64 {
        let m = |a: ArrayView2<'_, T>, h: f64| max_abs(a) / h;
        dt * m(ux, self.grid().dx).max(m(uy, self.grid().dy))
    }

    /// Checks a state and parameters and picks the number of substeps.
    fn plan<T: Real>(&self, s: &StateView<'_, T>, p: &FlowParams<T>) -> Result<(usize, f64)> {
        const STEP: &str = "flow step";
        let grid = self.grid();
        grid.check_velocity(STEP, s.ux, s.uy)?;
        grid.check_cells(STEP, "pressure", s.pressure)?;
        if s.scalars.len() != self.scalars() {
            return Err(FlowError::shape(
                STEP,
                "scalar list",
                &[self.scalars()],
                &[s.scalars.len()],
            ));
        }
        for a in &s.scalars {
            grid.check_cells(STEP, "scalar", *a)?;
        }
        grid.check_walls(STEP, p.wall_speed.view())?;
        self.faces().check_inflow(STEP, p.inflow.view())?;
        let finite = |quantity: &str, count: usize| -> Result<()> {
            if count == 0 {
                Ok(())
            } else {
                Err(FlowError::NonFinite {
                    step: STEP.into(),
                    quantity: quantity.into(),
                    count,
                })
            }
        };
        finite("x-velocity", nonfinite(s.ux.iter()))?;
        finite("y-velocity", nonfinite(s.uy.iter()))?;
        finite("pressure", nonfinite(s.pressure.iter()))?;
        for a in &s.scalars {
            finite("scalar", nonfinite(a.iter()))?;
        }
        finite("wall speeds", nonfinite(p.wall_speed.iter()))?;
        finite("inflow profile", nonfinite(p.inflow.iter()))?;
        let nu = p.viscosity.as_f64();
        if !(nu.is_finite() && nu > 0.0) {
            return Err(FlowError::parameter(
                STEP,
                "viscosity",
                format!("need a finite viscosity > 0, got {nu}"),
            ));
        }
        let dt = self.dt();
        // The inflow enters the domain too.
        let inflow_max = p.inflow.iter().fold(0.0f64, |m, v| m.max(v.as_f64().abs()));
        let h = grid.dx.min(grid.dy);
        let courant = self.courant(s.ux, s.uy, dt).max(inflow_max * dt / h);
        let limit = self.settings().max_courant;
        let mut n = 1;
        if courant > limit {
            if !self.settings().substepping {
                return Err(FlowError::Cfl {
                    step: "advection".into(),
                    quantity: "Courant".into(),
                    number: courant,
                    limit,
                });
            }
            n = (courant / limit).ceil() as usize;
        }
        if self.settings().viscosity_mode == ViscosityMode::Explicit {
            let d = explicit_diffusion_number(grid, nu, dt);
            if d > 0.5 {
                if !self.settings().substepping {
                    return Err(FlowError::Cfl {
                        step: "explicit diffusion".into(),
                        quantity: "diffusion".into(),
                        number: d,
                        limit: 0.5,
                    });
                }
                n = n.max((d / 0.5).ceil() as usize);
            }
        }
        Ok((n, courant))
    }

    /// One step on `tape`: every piece recorded as an op, the gradient through
    /// the state and the parameters available by `tape.backward`.
    ///
    /// # Errors
    /// [`FlowError`] naming the piece of the step and the quantity: shapes,
    /// NaN or infinity in the state or parameters, `ν ≤ 0`, a CFL violation
    /// without substepping, a failed pressure or viscosity solve.
    pub fn step<'t, T: Real>(
        &self,
        tape: &'t Tape<T>,
        state: &FlowVars<'t, T>,
        params: &ParamVars<'t, T>,
    ) -> Result<(FlowVars<'t, T>, StepInfo)> {
        // the tape's values, viewed (not copied) for the checks
        let held: Vec<_> = [state.ux, state.uy, state.pressure]
            .iter()
            .chain(&state.scalars)
            .map(|v| v.value())
            .collect();
        fn two<'a, T>(a: &'a ArrayD<T>, what: &str) -> Result<ArrayView2<'a, T>> {
            a.view()
                .into_dimensionality::<Ix2>()
                .map_err(|_| FlowError::shape("flow step", what, &[0, 0], a.shape()))
        }
        let s = StateView {
            ux: two(&held[0], "x-velocity")?,
            uy: two(&held[1], "y-velocity")?,
            pressure: two(&held[2], "pressure")?,
            scalars: held[3..]
                .iter()
                .map(|a| two(a, "scalar"))
                .collect::<Result<_>>()?,
        };
        let p = FlowParams {
            viscosity: params.viscosity.item().map_err(|_| {
                FlowError::shape("flow step", "viscosity", &[], &params.viscosity.shape())
            })?,
            wall_speed: params
                .wall_speed
                .to_array()
                .into_dimensionality()
                .map_err(|_| {
                    FlowError::shape("flow step", "wall speeds", &[4], &params.wall_speed.shape())
                })?,
            inflow: params
                .inflow
                .to_array()
                .into_dimensionality()
                .map_err(|_| {
                    FlowError::shape(
                        "flow step",
                        "inflow profile",
                        &[self.inflow_len()],
                        &params.inflow.shape(),
                    )
                })?,
        };
        let (n, courant) = self.plan(&s, &p)?;
        let exec = OnTape(tape);
        let counter = SolveCounter::new();
        let mut st = StateOf {
            ux: state.ux,
            uy: state.uy,
            pressure: state.pressure,
            scalars: state.scalars.clone(),
        };
        let pv = ParamsOf {
            viscosity: params.viscosity,
            wall_speed: params.wall_speed,
            inflow: params.inflow,
        };
        for _ in 0..n {
            st = substep(&exec, self, st, &pv, self.dt() / n as f64, &counter)?;
        }
        let info = StepInfo {
            substeps: n,
            courant,
            pressure_iterations: counter.iterations(),
        };
        Ok((
            FlowVars {
                ux: st.ux,
                uy: st.uy,
                pressure: st.pressure,
                scalars: st.scalars,
            },
            info,
        ))
    }

    /// One step without a tape: the same ops' forwards, no tape memory.
    ///
    /// A step whose kernels split runs whole on a thread of the pool
    /// ([`Scene::on_pool`]), so that its kernels and its pressure solve split
    /// across cores without handing work over at each call; the result is the
    /// same bits on any number of threads.
    ///
    /// # Errors
    /// As [`Scene::step`].
    pub fn forward<T: Real>(
        &self,
        state: &FlowState<T>,
        params: &FlowParams<T>,
    ) -> Result<(FlowState<T>, StepInfo)> {
        self.on_pool(|| self.forward_here(state, params))
    }

    /// Whether the step's kernels split across threads: its advection does
    /// from [`crate::advection::PARALLEL_FROM`] entries, the pressure solve
    /// and the tape's kernels from [`parallel::on_pool`]'s length.
    pub(crate) fn splits(&self) -> bool {
        self.grid().nx * self.grid().ny >= crate::advection::PARALLEL_FROM
    }

    /// Runs `f` on a thread of the pool if the step's kernels split there
    /// ([`parallel::to_pool`]), else here: for a caller that records a
    /// rollout on a tape of its own, created inside `f` (a tape stays on the
    /// thread that made it).
    pub fn on_pool<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        if self.splits() {
            parallel::to_pool(f)
        } else {
            f()
        }
    }

    /// [`Scene::forward`] on the calling thread.
    fn forward_here<T: Real>(
        &self,
        state: &FlowState<T>,
        params: &FlowParams<T>,
    ) -> Result<(FlowState<T>, StepInfo)> {
        let (n, courant) = self.plan(&state.view(), params)?;
        let counter = SolveCounter::new();
        let d = |a: &Array2<T>| a.clone().into_dyn();
        let mut st = StateOf {
            ux: d(&state.ux),
            uy: d(&state.uy),
            pressure: d(&state.pressure),
            scalars: state.scalars.iter().map(d).collect(),
        };
        let pv = ParamsOf {
            viscosity: ArrayD::from_elem(IxDyn(&[]), params.viscosity),
            wall_speed: params.wall_speed.clone().into_dyn(),
            inflow: params.inflow.clone().into_dyn(),
        };
        for _ in 0..n {
            st = substep(&Plain, self, st, &pv, self.dt() / n as f64, &counter)?;
        }
        let two = |a: ArrayD<T>| a.into_dimensionality().expect("the ops return 2D fields");
        Ok((
            FlowState {
                ux: two(st.ux),
                uy: two(st.uy),
                pressure: two(st.pressure),
                scalars: st.scalars.into_iter().map(two).collect(),
            },
            StepInfo {
                substeps: n,
                courant,
                pressure_iterations: counter.iterations(),
            },
        ))
    }

    /// The step as a [`StepFn`] for [`diffphys_tape::checkpointed_steps`]:
    /// state `[u_x, u_y, P, scalars…]` ([`FlowVars::to_vec`]), parameters
    /// `[ν, wall_speed, inflow]` ([`ParamVars::to_vec`]).
    pub fn step_fn<T: Real>(&self) -> Rc<StepFn<T>> {
        let scene = self.clone();
        let f: Rc<StepFn<T>> = Rc::new(move |tape, _k, state, params| {
            let s = FlowVars::from_slice(state).map_err(TapeError::from)?;
            let p = ParamVars::from_slice(params).map_err(TapeError::from)?;
            let (next, _) = scene.step(tape, &s, &p).map_err(TapeError::from)?;
            Ok(next.to_vec())
        });
        f
    }

    /// `steps` steps on `tape`, stored by `schedule` (checkpointed segments
    /// recompute their steps in the backward sweep).
    ///
    /// # Errors
    /// As [`Scene::step`]; errors inside a checkpointed segment come back as
    /// the [`FlowError`] they were.
    pub fn rollout<'t, T: Real>(
        &self,
        tape: &'t Tape<T>,
        schedule: Schedule,
        steps: usize,
        state: &FlowVars<'t, T>,
        params: &ParamVars<'t, T>,
    ) -> Result<FlowVars<'t, T>> {
        let out = checkpointed_steps(
            tape,
            schedule,
            steps,
            &state.to_vec(),
            &params.to_vec(),
            self.step_fn(),
        )?;
        FlowVars::from_slice(&out)
    }
}

impl AsRef<FlowGrid> for Scene {
    fn as_ref(&self) -> &FlowGrid {
        self.grid()
    }
}

/// How many of the values are NaN or infinite.
fn nonfinite<'a, T: Real>(values: impl Iterator<Item = &'a T>) -> usize {
    values.filter(|v| !v.is_finite()).count()
}

/// `max |v|` (0 for none), over eight running maxima so that the loop is not
/// one chain of dependent comparisons.
fn max_abs<T: Real>(a: ArrayView2<'_, T>) -> f64 {
    let mut m = [0.0f64; 8];
    let mut fold = |chunk: &[T]| {
        for (mi, v) in m.iter_mut().zip(chunk) {
            *mi = mi.max(v.as_f64().abs());
        }
    };
    match a.as_slice_memory_order() {
        Some(s) => s.chunks(8).for_each(&mut fold),
        None => a.iter().for_each(|v| fold(std::slice::from_ref(v))),
    }
    m.iter().fold(0.0f64, |x, &y| x.max(y))
}

/// A state's arrays, viewed.
struct StateView<'a, T> {
    ux: ArrayView2<'a, T>,
    uy: ArrayView2<'a, T>,
    pressure: ArrayView2<'a, T>,
    scalars: Vec<ArrayView2<'a, T>>,
}

impl<T: Real> FlowState<T> {
    fn view(&self) -> StateView<'_, T> {
        StateView {
            ux: self.ux.view(),
            uy: self.uy.view(),
            pressure: self.pressure.view(),
            scalars: self.scalars.iter().map(|a| a.view()).collect(),
        }
    }
}

/// The state as the executor's values.
struct StateOf<V> {
    ux: V,
    uy: V,
    pressure: V,
    scalars: Vec<V>,
}

/// The parameters as the executor's values.
struct ParamsOf<V> {
    viscosity: V,
    wall_speed: V,
    inflow: V,
}

/// Runs ops: recorded on a tape, or their forwards directly.
pub trait Exec<T: Real> {
    /// A value: a tape variable, or an array.
    type V: Clone;
    /// `op` applied to `inputs`.
    ///
    /// # Errors
    /// The op's error, as a [`FlowError`].
    fn run<O: Op<T> + 'static>(&self, op: O, inputs: &[&Self::V]) -> Result<Vec<Self::V>>;
}

/// Records on a tape.
struct OnTape<'t, T: Real>(&'t Tape<T>);

impl<'t, T: Real> Exec<T> for OnTape<'t, T> {
    type V = Var<'t, T>;
    fn run<O: Op<T> + 'static>(&self, op: O, inputs: &[&Var<'t, T>]) -> Result<Vec<Var<'t, T>>> {
        let vars: Vec<Var<'t, T>> = inputs.iter().map(|v| **v).collect();
        crate::record(self.0, op, &vars).map_err(FlowError::from_tape)
    }
}

/// Runs the forwards without a tape.
struct Plain;

impl<T: Real> Exec<T> for Plain {
    type V = ArrayD<T>;
    fn run<O: Op<T> + 'static>(&self, mut op: O, inputs: &[&ArrayD<T>]) -> Result<Vec<ArrayD<T>>> {
        let views: Vec<_> = inputs.iter().map(|a| a.view()).collect();
        op.forward(&views).map_err(FlowError::from_tape)
    }
}

fn two<V>(mut v: Vec<V>) -> (V, V) {
    let b = v.pop().expect("two outputs");
    let a = v.pop().expect("two outputs");
    (a, b)
}

/// One (sub)step of `dt`: the physics, piece by piece (see the module docs).
fn substep<T: Real, E: Exec<T>>(
    e: &E,
    scene: &Scene,
    s: StateOf<E::V>,
    p: &ParamsOf<E::V>,
    dt: f64,
    counter: &SolveCounter,
) -> Result<StateOf<E::V>> {
    let settings = scene.settings();
    let (grid, faces) = (scene.grid(), scene.faces());
    let (ux, uy) = if faces.all_free() {
        (s.ux, s.uy)
    } else {
        two(e.run(
            EnforceBoundaries {
                grid: grid.clone(),
                faces: Arc::clone(faces),
            },
            &[&s.ux, &s.uy, &p.inflow],
        )?)
    };
    let advect = AdvectScalar {
        grid: grid.clone(),
        faces: Arc::clone(faces),
        scheme: settings.advection,
        dt,
    };
    let scalars = s
        .scalars
        .iter()
        .map(|q| {
            Ok(e.run(advect.clone(), &[q, &ux, &uy, &p.wall_speed])?
                .remove(0))
        })
        .collect::<Result<Vec<_>>>()?;
    let incremental = settings.splitting == Splitting::Incremental;
    let (qx, qy) = if incremental {
        two(e.run(
            SubtractPressureGradient {
                grid: grid.clone(),
                faces: Arc::clone(faces),
                c: dt / 2.0,
            },
            &[&ux, &uy, &s.pressure],
        )?)
    } else {
        (ux.clone(), uy.clone())
    };
    let advect = AdvectVelocity {
        grid: grid.clone(),
        faces: Arc::clone(faces),
        scheme: settings.advection,
        dt,
    };
    let (ux, mut uy) = two(e.run(advect, &[&qx, &qy, &ux, &uy, &p.wall_speed])?);
    if let Some(b) = scene.0.buoyancy {
        uy = e
            .run(
                Buoyant {
                    grid: grid.clone(),
                    faces: Arc::clone(faces),
                    beta: b.beta,
                    dt,
                },
                &[&uy, &scalars[b.scalar]],
            )?
            .remove(0);
    }
    let (ux, uy) = two(e.run(
        Diffuse {
            diffusion: Arc::clone(scene.diffusion()),
            mode: settings.viscosity_mode,
            dt,
        },
        &[&ux, &uy, &p.viscosity, &p.wall_speed],
    )?);
    let tau = if incremental { dt / 2.0 } else { dt };
    let mut out = e.run(
        Project {
            system: Arc::clone(scene.pressure_system()),
            tau,
            counter: counter.clone(),
        },
        &[&ux, &uy, &s.pressure],
    )?;
    let pressure = out.pop().expect("three outputs");
    let (ux, uy) = two(out);
    Ok(StateOf {
        ux,
        uy,
        pressure,
        scalars,
    })
}
