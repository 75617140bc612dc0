//! The solvers of the scene: how each resolution sees the cylinder, the
//! coarse, reference and finer uncorrected scenes.

use diffphys::flow::{Advection, Boundary, Obstacle, PressureSolver, Scene, Sides, Splitting};
use ndarray::Array2;

use super::{
    name_in, viscosity, Result, Sizes, WakeError, CENTRE, DIAMETER, FACTOR, LX, LY, RE_CENTRE, U_IN,
};

/// How each resolution of the scene sees the cylinder (`--body`; default
/// [`Body::Inscribed`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Body {
    /// Every grid rasterises the cylinder itself: its solid cells are those
    /// whose centre lies within the radius. The reference resolves the round
    /// body; the coarse solver pins to zero some faces where the restricted
    /// reference is not zero (a coarse solid cell partly fluid on the fine
    /// grid), an error no correction of the free faces can remove: 1.1–2.2 %
    /// of the state's norm at 32 × 64 (the scene's default until 2026-11-27).
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
    /// reference keeps the round body. The default: chosen on validation
    /// (docs/11, "Where the corrected error's level comes from").
    Inscribed,
}

impl Body {
    /// Every body, by its `--body` name.
    pub const ALL: [(&'static str, Body); 3] = [
        ("cylinder", Body::Cylinder),
        ("staircase", Body::Staircase),
        ("inscribed", Body::Inscribed),
    ];

    /// Its `--body` name.
    pub fn label(self) -> &'static str {
        name_in(&Self::ALL, self)
    }
}

/// The reference's scheme (`--reference-scheme`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReferenceScheme {
    /// MacCormack advection with the limiter and incremental splitting: a
    /// better scheme than the coarse one, not only a finer grid.
    SecondOrder,
    /// The coarse solver's own scheme (semi-Lagrangian, plain splitting) at
    /// the reference's resolution, as in the JAX prototype the issue quotes.
    Coarse,
}

impl ReferenceScheme {
    /// Every scheme, by its `--reference-scheme` name.
    pub const ALL: [(&'static str, ReferenceScheme); 2] = [
        ("second-order", ReferenceScheme::SecondOrder),
        ("coarse", ReferenceScheme::Coarse),
    ];

    /// Its `--reference-scheme` name.
    pub fn label(self) -> &'static str {
        name_in(&Self::ALL, self)
    }
}

/// The solid cells of the scene at `level` times the coarse resolution.
///
/// # Errors
/// [`WakeError::Flow`] if the cylinder does not fit the coarse grid.
pub fn obstacle(sizes: &Sizes, level: usize) -> Result<Obstacle> {
    let cylinder = Obstacle::cylinder(CENTRE, DIAMETER / 2.0);
    match sizes.body {
        Body::Cylinder => Ok(cylinder),
        Body::Staircase => {
            let coarse = Scene::builder(sizes.nx, sizes.ny, [LX, LY])
                .obstacle(cylinder)
                .build()?;
            let solid = coarse.solid();
            Ok(Obstacle::Mask(Array2::from_shape_fn(
                (level * sizes.nx, level * sizes.ny),
                |(i, j)| solid[[i / level, j / level]],
            )))
        }
        Body::Inscribed => {
            if FACTOR % level != 0 {
                return Err(WakeError::Argument {
                    option: "--body".into(),
                    message: format!(
                        "an inscribed body needs a level dividing {FACTOR}, not {level}"
                    ),
                });
            }
            let k = FACTOR / level;
            if k == 1 {
                // The reference grid: the cylinder itself.
                return Ok(cylinder);
            }
            let fine = Scene::builder(FACTOR * sizes.nx, FACTOR * sizes.ny, [LX, LY])
                .obstacle(cylinder)
                .build()?;
            let solid = fine.solid();
            Ok(Obstacle::Mask(Array2::from_shape_fn(
                (level * sizes.nx, level * sizes.ny),
                |(i, j)| (0..k).all(|a| (0..k).all(|b| solid[[k * i + a, k * j + b]])),
            )))
        }
    }
}

/// The wake channel at `nx × ny` cells with time step `dt`, the given
/// advection, splitting, pressure solver and body.
pub fn wake_scene(
    nx: usize,
    ny: usize,
    dt: f64,
    scheme: (Advection, Splitting),
    pressure: PressureSolver,
    body: Obstacle,
) -> Result<Scene> {
    let (advection, splitting) = scheme;
    Ok(Scene::builder(nx, ny, [LX, LY])
        .sides(Sides {
            left: Boundary::Inflow,
            right: Boundary::Outflow,
            bottom: Boundary::FreeSlip,
            top: Boundary::FreeSlip,
        })
        .obstacle(body)
        .uniform_inflow(U_IN)
        .viscosity(viscosity(RE_CENTRE))
        .dt(dt)
        .advection(advection)
        .splitting(splitting)
        .pressure_solver(pressure)
        // Semi-Lagrangian advection is stable at any Courant number (a
        // corrected state, early in training, may run much faster than the
        // inflow: its error says so, not a refused step); MacCormack is not,
        // and substeps instead.
        .max_courant(if advection == Advection::SemiLagrangian {
            1e3
        } else {
            1.0
        })
        .substepping(advection != Advection::SemiLagrangian)
        .build()?)
}

/// The coarse solver's scheme at `level` times the coarse resolution
/// (`dt / level`): the advection and splitting of `sizes`.
pub fn uncorrected(sizes: &Sizes, level: usize, pressure: PressureSolver) -> Result<Scene> {
    wake_scene(
        level * sizes.nx,
        level * sizes.ny,
        sizes.dt / level as f64,
        (sizes.advection, sizes.splitting),
        pressure,
        obstacle(sizes, level)?,
    )
}

/// The reference solver: [`FACTOR`]× finer, MacCormack with the limiter and
/// incremental splitting (or the coarse scheme: [`ReferenceScheme`]).
pub fn reference_scene(sizes: &Sizes) -> Result<Scene> {
    reference_scene_at(sizes, FACTOR)
}

/// The reference's scheme at `factor`× the coarse resolution (`dt / factor`):
/// [`reference_scene`] at [`FACTOR`], its convergence check at `2 FACTOR`.
/// A body inscribed at the reference's resolution is the cylinder itself at
/// any finer one.
pub fn reference_scene_at(sizes: &Sizes, factor: usize) -> Result<Scene> {
    let scheme = match sizes.reference {
        ReferenceScheme::SecondOrder => (
            Advection::MacCormack { limiter: true },
            Splitting::Incremental,
        ),
        ReferenceScheme::Coarse => (sizes.advection, Splitting::Plain),
    };
    let body = if sizes.body == Body::Inscribed && factor > FACTOR {
        Obstacle::cylinder(CENTRE, DIAMETER / 2.0)
    } else {
        obstacle(sizes, factor)?
    };
    wake_scene(
        factor * sizes.nx,
        factor * sizes.ny,
        sizes.dt / factor as f64,
        scheme,
        PressureSolver::Cholesky,
        body,
    )
}
