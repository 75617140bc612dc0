//! A body in a channel, the scene family of a hybrid wake study: the
//! geometry ([`Channel`]), how each resolution sees the body ([`Body`]), the
//! reference's scheme ([`ReferenceScheme`]), the sizes and schedule of a run
//! ([`Sizes`]), and [`Wake`], which builds the coarse, reference and finer
//! uncorrected solvers, generates and caches the reference
//! ([`Wake::reference`]), saves and re-evaluates correctors
//! ([`Wake::card`], [`Wake::evaluate`]), checks the reference against one
//! level finer ([`Wake::convergence`]) and measures speed against accuracy
//! ([`Wake::speed`], [`Wake::pressure_solves`]).
//!
//! The channel: uniform inflow on the left, outflow on the right, free-slip
//! side walls, a cylinder rasterised on the reference grid; `Re = U D / ν`
//! with `U` the inflow speed and `D` the cylinder's diameter. A scene states
//! its [`Channel`] and [`Sizes`]; the example `wake_flow` is one.

pub mod args;
mod convergence;
mod data;
mod measure;
mod saved;
pub mod study;

pub use data::Bump;
pub use saved::{Evaluation, KIND};

use diffphys_flow::{Advection, Boundary, Obstacle, PressureSolver, Scene, Sides, Splitting};
use diffphys_nn::Arithmetic;
use ndarray::Array2;

use crate::{HybridError, Result};

/// The geometry of a wake channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Channel {
    /// The domain's length along the flow and its width.
    pub extent: [f64; 2],
    /// The cylinder's centre.
    pub centre: [f64; 2],
    /// The cylinder's diameter (the length of `Re`).
    pub diameter: f64,
    /// The inflow speed (the speed of `Re`).
    pub inflow: f64,
    /// The reference's refinement in space and time.
    pub factor: usize,
    /// The refinement at which an inscribed body ([`Body::Inscribed`]) is
    /// the cylinder rasterised: a coarser level's cell is solid where every
    /// cell of this level inside it is, a level at or above it sees the
    /// cylinder itself. It stays put when the reference is refined, so
    /// that the coarse solver's body does not change with the reference.
    pub inscribed_at: usize,
    /// The Reynolds numbers a user may ask for.
    pub re_range: [f64; 2],
    /// The Reynolds number a scene is built at before each sample sets its
    /// own viscosity.
    pub re_centre: f64,
}

impl Channel {
    /// The viscosity of `re`: `U D / Re`.
    pub fn viscosity(&self, re: f64) -> f64 {
        self.inflow * self.diameter / re
    }

    /// `re` if it lies in the channel's range.
    ///
    /// # Errors
    /// [`HybridError::ReOutOfRange`].
    pub fn checked_re(&self, re: f64) -> Result<f64> {
        let [lo, hi] = self.re_range;
        if re.is_finite() && (lo..=hi).contains(&re) {
            Ok(re)
        } else {
            Err(HybridError::ReOutOfRange {
                re,
                range: self.re_range,
            })
        }
    }
}

/// The name of `value` in a table of names (`"?"` if absent).
pub fn name_in<T: PartialEq>(table: &[(&'static str, T)], value: T) -> &'static str {
    table
        .iter()
        .find(|(_, v)| *v == value)
        .map_or("?", |(n, _)| n)
}

/// The coarse solver's advection schemes, by their command-line names.
pub const ADVECTIONS: [(&str, Advection); 2] = [
    ("semi-lagrangian", Advection::SemiLagrangian),
    ("maccormack", Advection::MacCormack { limiter: true }),
];

/// The coarse solver's splittings, by their command-line names.
pub const SPLITTINGS: [(&str, Splitting); 2] = [
    ("plain", Splitting::Plain),
    ("incremental", Splitting::Incremental),
];

/// The corrector's convolution arithmetics, by their command-line names.
pub const ARITHMETICS: [(&str, Arithmetic); 2] =
    [("f32", Arithmetic::Single), ("f64", Arithmetic::Native)];

/// How each resolution of the scene sees the cylinder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Body {
    /// Every grid rasterises the cylinder itself: its solid cells are those
    /// whose centre lies within the radius. The reference resolves the round
    /// body; the coarse solver pins to zero some faces where the restricted
    /// reference is not zero (a coarse solid cell partly fluid on the fine
    /// grid), an error no correction of the free faces can remove.
    Cylinder,
    /// Every grid uses the coarse grid's staircase (the coarse solid cells,
    /// refined): the reference resolves the body the coarse solver
    /// represents, so every face the coarse solver pins is zero in the
    /// restricted reference too.
    Staircase,
    /// The reference rasterises the cylinder; a coarser grid makes solid only
    /// its cells that are solid throughout on the reference grid (the
    /// staircase inscribed in the reference's body), so every face the
    /// coarse solver pins is zero in the restricted reference while the
    /// reference keeps the round body.
    Inscribed,
}

impl Body {
    /// Every body, by its command-line name.
    pub const ALL: [(&'static str, Body); 3] = [
        ("cylinder", Body::Cylinder),
        ("staircase", Body::Staircase),
        ("inscribed", Body::Inscribed),
    ];

    /// Its command-line name.
    pub fn label(self) -> &'static str {
        name_in(&Self::ALL, self)
    }
}

/// The reference's scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReferenceScheme {
    /// MacCormack advection with the limiter and incremental splitting: a
    /// better scheme than the coarse one, not only a finer grid.
    SecondOrder,
    /// The coarse solver's own scheme (plain splitting) at the reference's
    /// resolution.
    Coarse,
}

impl ReferenceScheme {
    /// Every scheme, by its command-line name.
    pub const ALL: [(&'static str, ReferenceScheme); 2] = [
        ("second-order", ReferenceScheme::SecondOrder),
        ("coarse", ReferenceScheme::Coarse),
    ];

    /// Its command-line name.
    pub fn label(self) -> &'static str {
        name_in(&Self::ALL, self)
    }
}

/// The sizes and schedule of one run of a wake scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Sizes {
    /// Coarse cells along x (streamwise).
    pub nx: usize,
    /// Coarse cells along y.
    pub ny: usize,
    /// The coarse time step.
    pub dt: f64,
    /// Coarse steps from the start state to the split's base state.
    pub warm_base: usize,
    /// Coarse steps from the base state at each Re before recording (the
    /// skipped transient).
    pub warm: usize,
    /// Coarse steps recorded per Re.
    pub record: usize,
    /// The base state's Reynolds number.
    pub base_re: f64,
    /// Rollout length of the headline figure.
    pub rollout: usize,
    /// Its start steps in the recorded trajectory.
    pub starts: Vec<usize>,
    /// The long rollout (from step 0).
    pub long: usize,
    /// The starts of the speed study's rollouts (a subset of `starts`: the
    /// finest solver is the costly part).
    pub speed_starts: Vec<usize>,
    /// The coarse (uncorrected and corrected) solver's advection, also at the
    /// speed study's finer levels.
    pub advection: Advection,
    /// The coarse solver's splitting (also at the speed study's finer
    /// levels): with [`Splitting::Incremental`] its state carries the
    /// pressure, an auxiliary field.
    pub splitting: Splitting,
    /// How each resolution sees the cylinder.
    pub body: Body,
    /// The reference's scheme.
    pub reference: ReferenceScheme,
}

/// A wake scene: its channel and the sizes of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct Wake {
    /// The geometry.
    pub channel: Channel,
    /// The grids, steps and schemes.
    pub sizes: Sizes,
}

impl Wake {
    /// The solid cells of the scene at `level` times the coarse resolution.
    ///
    /// # Errors
    /// [`HybridError::Flow`] if the cylinder does not fit the coarse grid;
    /// [`HybridError::Setting`] for an inscribed body at a level that does
    /// not divide the reference's factor.
    pub fn obstacle(&self, level: usize) -> Result<Obstacle> {
        let (c, s) = (&self.channel, &self.sizes);
        let cylinder = Obstacle::cylinder(c.centre, c.diameter / 2.0);
        match s.body {
            Body::Cylinder => Ok(cylinder),
            Body::Staircase => {
                let coarse = Scene::builder(s.nx, s.ny, c.extent)
                    .obstacle(cylinder)
                    .build()?;
                let solid = coarse.solid();
                Ok(Obstacle::Mask(Array2::from_shape_fn(
                    (level * s.nx, level * s.ny),
                    |(i, j)| solid[[i / level, j / level]],
                )))
            }
            Body::Inscribed => {
                let base = c.inscribed_at;
                if level >= base && level > 0 {
                    // At or above the inscription's resolution: the cylinder.
                    return Ok(cylinder);
                }
                if level == 0 || base % level != 0 {
                    return Err(HybridError::Setting {
                        what: "body",
                        message: format!(
                            "an inscribed body needs a level dividing {base} or at least it, not {level}"
                        ),
                    });
                }
                let k = base / level;
                let fine = Scene::builder(base * s.nx, base * s.ny, c.extent)
                    .obstacle(cylinder)
                    .build()?;
                let solid = fine.solid();
                Ok(Obstacle::Mask(Array2::from_shape_fn(
                    (level * s.nx, level * s.ny),
                    |(i, j)| (0..k).all(|a| (0..k).all(|b| solid[[k * i + a, k * j + b]])),
                )))
            }
        }
    }

    /// The channel at `nx × ny` cells with time step `dt`, the given
    /// advection, splitting, pressure solver and body.
    ///
    /// # Errors
    /// [`HybridError::Flow`] where the scene's builder refuses.
    pub fn scene(
        &self,
        [nx, ny]: [usize; 2],
        dt: f64,
        (advection, splitting): (Advection, Splitting),
        pressure: PressureSolver,
        body: Obstacle,
    ) -> Result<Scene> {
        let c = &self.channel;
        Ok(Scene::builder(nx, ny, c.extent)
            .sides(Sides {
                left: Boundary::inflow(),
                right: Boundary::outflow(),
                bottom: Boundary::free_slip(),
                top: Boundary::free_slip(),
            })
            .obstacle(body)
            .uniform_inflow(c.inflow)
            .viscosity(c.viscosity(c.re_centre))
            .dt(dt)
            .advection(advection)
            .splitting(splitting)
            .pressure_solver(pressure)
            // Semi-Lagrangian advection is stable at any Courant number (a
            // corrected state, early in training, may run much faster than
            // the inflow: its error says so, not a refused step); MacCormack
            // is not, and substeps instead.
            .max_courant(if advection == Advection::SemiLagrangian {
                1e3
            } else {
                1.0
            })
            .substepping(advection != Advection::SemiLagrangian)
            .build()?)
    }

    /// The coarse solver's scheme at `level` times the coarse resolution
    /// (`dt / level`): the advection and splitting of the sizes.
    ///
    /// # Errors
    /// As [`Wake::obstacle`] and [`Wake::scene`].
    pub fn uncorrected(&self, level: usize, pressure: PressureSolver) -> Result<Scene> {
        let s = &self.sizes;
        self.scene(
            [level * s.nx, level * s.ny],
            s.dt / level as f64,
            (s.advection, s.splitting),
            pressure,
            self.obstacle(level)?,
        )
    }

    /// The reference solver: the channel's factor finer, MacCormack with the
    /// limiter and incremental splitting (or the coarse scheme:
    /// [`ReferenceScheme`]).
    ///
    /// # Errors
    /// As [`Wake::reference_scene_at`].
    pub fn reference_scene(&self) -> Result<Scene> {
        self.reference_scene_at(self.channel.factor)
    }

    /// The reference's scheme at `factor`× the coarse resolution
    /// (`dt / factor`): [`Wake::reference_scene`] at the channel's factor,
    /// its convergence check at twice it. An inscribed body is the cylinder
    /// itself at and above [`Channel::inscribed_at`].
    ///
    /// # Errors
    /// As [`Wake::obstacle`] and [`Wake::scene`].
    pub fn reference_scene_at(&self, factor: usize) -> Result<Scene> {
        let s = &self.sizes;
        let scheme = match s.reference {
            ReferenceScheme::SecondOrder => (
                Advection::MacCormack { limiter: true },
                Splitting::Incremental,
            ),
            ReferenceScheme::Coarse => (s.advection, Splitting::Plain),
        };
        let body = self.obstacle(factor)?;
        self.scene(
            [factor * s.nx, factor * s.ny],
            s.dt / factor as f64,
            scheme,
            PressureSolver::Cholesky,
            body,
        )
    }
}
