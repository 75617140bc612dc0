//! The physics and the network of `wake_flow`: the coarse wake solver as a
//! batched simulator, the reference solver, the corrector, the options and the
//! scene's typed errors.
//!
//! Geometry (units: inflow speed U = 1, cylinder diameter D = 0.2): a channel
//! 2 long (x, streamwise) and 1 wide (y), uniform inflow 1 on the left, outflow
//! on the right, free-slip side walls, a cylinder of radius 0.1 centred at
//! (0.5, 0.5), rasterised on the reference grid; a coarser grid's body is the
//! staircase inscribed in it ([`Body`]). `Re = U D / ν`.
//!
//! - coarse: `ny × nx` = 32 × 64 cells (16 × 32 with `--small`),
//!   semi-Lagrangian self-advection, explicit viscosity, plain (first-order)
//!   splitting, sparse Cholesky pressure solve, `dt` = 0.01 (Courant 0.32 at
//!   the inflow speed);
//! - reference: 4× finer in space and time (128 × 256, `dt / 4`), MacCormack
//!   advection with the limiter and incremental (second-order) splitting,
//!   restricted to the coarse grid by face averages
//!   ([`diffphys::flow::restrict_velocity`]);
//! - uncorrected finer solvers for the speed study: the coarse scheme at 2×
//!   and 4× the resolution (`dt / 2`, `dt / 4`).
//!
//! A coarse state is packed as `[2, nx + 1, ny + 1]` with its viscosity in a
//! corner ([`diffphys::flow::packed`]), so one batch mixes Reynolds numbers.

pub mod cli;
pub mod data;
pub mod model;
pub mod study;

use diffphys::flow::{
    Advection, Boundary, FlowError, Obstacle, PressureSolver, Scene, Sides, Splitting,
};
use diffphys::learn::{standard_normal, Corrector, LearnError, Simulator, Split};
use diffphys::nn::{Arithmetic, Bound, Conv2, ConvConfig, Init, Layer, NnError, Padding, Params};
use diffphys::tape::{ArrayD, TapeError, Var};
use ndarray::Array2;
use rand::rngs::StdRng;
use rand::Rng;

/// The domain's length along the flow.
pub const LX: f64 = 2.0;
/// Its width.
pub const LY: f64 = 1.0;
/// The cylinder's centre.
pub const CENTRE: [f64; 2] = [0.5, 0.5];
/// The cylinder's diameter (the length of `Re`).
pub const DIAMETER: f64 = 0.2;
/// The inflow speed.
pub const U_IN: f64 = 1.0;
/// The reference's refinement in space and time.
pub const FACTOR: usize = 4;
/// The Reynolds numbers a user may ask for (`--held-out-re`).
pub const RE_RANGE: [f64; 2] = [50.0, 3200.0];
/// The Reynolds number the network's Re channel is centred on.
pub const RE_CENTRE: f64 = 400.0;

/// Everything that can go wrong in the scene.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WakeError {
    /// A variant name that is not one of `src, non, noise, solK`.
    #[error("unknown variant {name:?}: choose from src, non, noise, sol4, sol16")]
    UnknownVariant {
        /// What was asked for.
        name: String,
    },
    /// A Reynolds number outside [`RE_RANGE`] (or not finite).
    #[error("Reynolds number {re} is outside the scene's range [50, 3200]")]
    ReOutOfRange {
        /// What was asked for.
        re: f64,
    },
    /// A bad command-line argument.
    #[error("{option}: {message}")]
    Argument {
        /// The option.
        option: String,
        /// What is wrong.
        message: String,
    },
    /// The reference carries flow on faces the coarse solver pins although
    /// the body was built so that it cannot ([`Body::Staircase`],
    /// [`Body::Inscribed`]).
    #[error("the reference carries flow on faces the coarse solver pins (relative {error:.3e} at Re {re}) although the {body} body was built to rule that out")]
    PinnedFaces {
        /// The body.
        body: &'static str,
        /// The Reynolds number.
        re: f64,
        /// The pinned-face error.
        error: f64,
    },
    /// The reference cache could not be read or written.
    #[error("reference cache {path}: {message}")]
    Cache {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// The learning library refused (empty split, unroll 0, corrector shape, …).
    #[error(transparent)]
    Learn(#[from] LearnError),
    /// The flow solver refused.
    #[error(transparent)]
    Flow(#[from] FlowError),
    /// A network layer refused.
    #[error(transparent)]
    Nn(#[from] NnError),
    /// A tape op refused.
    #[error(transparent)]
    Tape(#[from] TapeError),
    /// Writing a chart or a file failed.
    #[error("output: {0}")]
    Output(String),
}

/// The scene's result type.
pub type Result<T> = std::result::Result<T, WakeError>;

/// The viscosity of `re`.
pub fn viscosity(re: f64) -> f64 {
    U_IN * DIAMETER / re
}

/// `re` if it lies in [`RE_RANGE`].
///
/// # Errors
/// [`WakeError::ReOutOfRange`].
pub fn checked_re(re: f64) -> Result<f64> {
    if re.is_finite() && (RE_RANGE[0]..=RE_RANGE[1]).contains(&re) {
        Ok(re)
    } else {
        Err(WakeError::ReOutOfRange { re })
    }
}

/// The network's Re input: `ln(Re / RE_CENTRE) / ln 4`, about −1.5 to 1.5 over
/// [`RE_RANGE`].
pub fn re_code(nu: f64) -> f64 {
    let re = U_IN * DIAMETER / nu;
    (re / RE_CENTRE).ln() / 4f64.ln()
}

/// Corrector evaluations per Adam step, at least: one window of `sol_4`, four
/// one-step pairs of `non`. Chosen on validation: at an equal budget of 24,000
/// evaluations, `sol_4`'s validation error with 16, 8 and 4 evaluations per
/// step (1,500, 3,000, 6,000 steps) was 0.042 / 0.064, 0.038 / 0.053 and
/// 0.032 / 0.040 (training seeds 1 / 2), `non`'s with 16 and 4 was
/// 0.080 / 0.084 and 0.061 / 0.067: more, smaller steps buy more than larger
/// batches (docs/11, "Smaller steps").
pub const STEP_EVALUATIONS: usize = 4;

/// One of the trained or untrained solvers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Variant {
    /// The coarse solver alone.
    Src,
    /// Supervised on one-step pairs.
    Non,
    /// As `Non`, with input noise.
    Noise,
    /// Solver in the loop over `k` steps.
    Sol(usize),
}

impl Variant {
    /// Parses `src`, `non`, `noise`, `solK` (`sol4`, `sol16`, …).
    ///
    /// # Errors
    /// [`WakeError::UnknownVariant`]; [`WakeError::Learn`] with
    /// [`LearnError::ZeroUnroll`] for `sol0`.
    pub fn parse(name: &str) -> Result<Self> {
        let unknown = || WakeError::UnknownVariant {
            name: name.to_string(),
        };
        match name.trim() {
            "src" => Ok(Variant::Src),
            "non" => Ok(Variant::Non),
            "noise" => Ok(Variant::Noise),
            s => {
                let k: usize = s
                    .strip_prefix("sol")
                    .map(|k| k.trim_start_matches(['-', '_']))
                    .and_then(|k| k.parse().ok())
                    .ok_or_else(unknown)?;
                if k == 0 {
                    return Err(LearnError::ZeroUnroll {
                        what: "solver in the loop",
                    }
                    .into());
                }
                Ok(Variant::Sol(k))
            }
        }
    }

    /// `src`, `non`, `noise`, `sol_k`.
    pub fn name(&self) -> String {
        match self {
            Variant::Src => "src".into(),
            Variant::Non => "non".into(),
            Variant::Noise => "noise".into(),
            Variant::Sol(k) => format!("sol_{k}"),
        }
    }

    /// Corrector evaluations per Adam step: the smallest multiple of the
    /// unroll (1 for `non` and `noise`) that is at least [`STEP_EVALUATIONS`],
    /// so a step holds whole windows (`sol_16`: one window of 16).
    pub fn step_evaluations(&self) -> usize {
        let k = match *self {
            Variant::Sol(k) => k.max(1),
            _ => 1,
        };
        k * STEP_EVALUATIONS.div_ceil(k)
    }

    /// Adam steps of a training with a budget of `evaluations`: the budget
    /// over [`Variant::step_evaluations`], at least one step for any budget
    /// but 0 (which stays 0, for the trainer to refuse).
    pub fn adam_steps(&self, evaluations: usize) -> usize {
        if evaluations == 0 {
            0
        } else {
            (evaluations / self.step_evaluations()).max(1)
        }
    }
}

/// A comma-separated list of Reynolds numbers, each checked.
///
/// # Errors
/// [`WakeError::Argument`] for text that is not a number;
/// [`WakeError::ReOutOfRange`]; [`LearnError::EmptySplit`] for an empty list.
pub fn parse_re_list(option: &str, text: &str, split: Split) -> Result<Vec<f64>> {
    let list = text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<f64>().map_err(|_| WakeError::Argument {
                option: option.into(),
                message: format!("not a number: {s:?}"),
            })
        })
        .map(|r| r.and_then(checked_re))
        .collect::<Result<Vec<_>>>()?;
    if list.is_empty() {
        return Err(LearnError::EmptySplit {
            split,
            context: format!("{option} lists no Reynolds number"),
        }
        .into());
    }
    Ok(list)
}

/// A comma-separated list, each entry parsed by `parse` (`None`: not
/// `what`).
///
/// # Errors
/// [`WakeError::Argument`] for an entry `parse` refuses, or no entry.
pub fn checked_list<T>(
    option: &str,
    what: &str,
    text: &str,
    parse: impl Fn(&str) -> Option<T>,
) -> Result<Vec<T>> {
    let argument = |message: String| WakeError::Argument {
        option: option.into(),
        message,
    };
    let list = text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| parse(s).ok_or_else(|| argument(format!("not {what}: {s:?}"))))
        .collect::<Result<Vec<T>>>()?;
    if list.is_empty() {
        return Err(argument(format!("lists no {what}")));
    }
    Ok(list)
}

/// The scene's sizes and schedule of one run (full or `--small`).
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
    /// 4× solver is the costly part).
    pub speed_starts: Vec<usize>,
    /// The coarse (uncorrected and corrected) solver's advection, also at the
    /// speed study's finer levels.
    pub advection: Advection,
    /// How each resolution sees the cylinder.
    pub body: Body,
    /// The reference's scheme.
    pub reference: ReferenceScheme,
}

impl Sizes {
    /// The full or small scene with the schemes and body of `options`.
    pub fn of(options: &Options, small: bool) -> Self {
        Sizes {
            advection: options.coarse_advection,
            body: options.body,
            reference: options.reference,
            ..if small { Sizes::small() } else { Sizes::full() }
        }
    }

    /// The full scene.
    pub fn full() -> Self {
        Sizes {
            nx: 64,
            ny: 32,
            dt: 0.01,
            warm_base: 600,
            warm: 200,
            record: 250,
            base_re: 400.0,
            rollout: 100,
            starts: vec![0, 50, 100, 150],
            long: 240,
            speed_starts: vec![0, 100],
            advection: Advection::SemiLagrangian,
            body: Body::Inscribed,
            reference: ReferenceScheme::SecondOrder,
        }
    }

    /// CI: 16 × 32 cells, short trajectories.
    pub fn small() -> Self {
        Sizes {
            nx: 32,
            ny: 16,
            dt: 0.02,
            warm_base: 60,
            warm: 20,
            record: 40,
            base_re: 400.0,
            rollout: 16,
            starts: vec![0, 16],
            long: 36,
            speed_starts: vec![0, 16],
            advection: Advection::SemiLagrangian,
            body: Body::Inscribed,
            reference: ReferenceScheme::SecondOrder,
        }
    }
}

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

/// The coarse solver's advection schemes, by their `--coarse-advection` name.
pub const ADVECTIONS: [(&str, Advection); 2] = [
    ("semi-lagrangian", Advection::SemiLagrangian),
    ("maccormack", Advection::MacCormack { limiter: true }),
];

/// The `--coarse-advection` name of `advection`.
pub fn advection_label(advection: Advection) -> &'static str {
    name_in(&ADVECTIONS, advection)
}

/// The corrector's convolution arithmetic, by its `--network-arithmetic` name.
/// `f32` is the default: on validation it trains as well as `f64` in about
/// 0.8× the time (docs/11, "Cost").
pub const ARITHMETICS: [(&str, Arithmetic); 2] =
    [("f32", Arithmetic::Single), ("f64", Arithmetic::Native)];

/// The `--network-arithmetic` name of `arithmetic`.
pub fn arithmetic_label(arithmetic: Arithmetic) -> &'static str {
    name_in(&ARITHMETICS, arithmetic)
}

/// The name of `value` in a table of names.
fn name_in<T: PartialEq>(table: &[(&'static str, T)], value: T) -> &'static str {
    table
        .iter()
        .find(|(_, v)| *v == value)
        .map_or("?", |(n, _)| n)
}

/// The value named `name` in a table of names; an argument error for
/// `option` listing the names otherwise.
pub fn parse_named<T: Copy>(table: &[(&'static str, T)], option: &str, name: &str) -> Result<T> {
    table
        .iter()
        .find(|(n, _)| *n == name.trim())
        .map(|(_, v)| *v)
        .ok_or_else(|| WakeError::Argument {
            option: option.into(),
            message: format!(
                "{name:?} is not one of {}",
                table.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ")
            ),
        })
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
/// (`dt / level`): the advection of `sizes`, plain splitting (a packed state
/// carries no pressure).
pub fn uncorrected(sizes: &Sizes, level: usize, pressure: PressureSolver) -> Result<Scene> {
    wake_scene(
        level * sizes.nx,
        level * sizes.ny,
        sizes.dt / level as f64,
        (sizes.advection, Splitting::Plain),
        pressure,
        obstacle(sizes, level)?,
    )
}

/// The reference solver: [`FACTOR`]× finer, MacCormack with the limiter and
/// incremental splitting (or the coarse scheme: [`ReferenceScheme`]).
pub fn reference_scene(sizes: &Sizes) -> Result<Scene> {
    let scheme = match sizes.reference {
        ReferenceScheme::SecondOrder => (
            Advection::MacCormack { limiter: true },
            Splitting::Incremental,
        ),
        ReferenceScheme::Coarse => (sizes.advection, Splitting::Plain),
    };
    wake_scene(
        FACTOR * sizes.nx,
        FACTOR * sizes.ny,
        sizes.dt / FACTOR as f64,
        scheme,
        PressureSolver::Cholesky,
        obstacle(sizes, FACTOR)?,
    )
}

/// The coarse solver as the learning library's simulator: one packed step of
/// a batch `[batch, 2, nx + 1, ny + 1]`; input noise only on the
/// [`free_faces`].
#[derive(Debug, Clone)]
pub struct Coarse {
    /// The coarse scene.
    pub scene: Scene,
    free: ArrayD<f64>,
}

impl Coarse {
    /// The simulator of `scene`.
    pub fn new(scene: Scene) -> Self {
        let free = free_faces(&scene);
        Coarse { scene, free }
    }
}

impl Simulator for Coarse {
    fn step<'t>(&self, state: Var<'t, f64>) -> diffphys::tape::Result<Var<'t, f64>> {
        Ok(self.scene.step_packed(state)?)
    }

    fn step_plain(&self, state: &ArrayD<f64>) -> diffphys::tape::Result<ArrayD<f64>> {
        Ok(self.scene.forward_packed(state.view())?)
    }

    fn perturb(&self, state: &mut ArrayD<f64>, sigma: f64, rng: &mut StdRng) {
        for mut sample in state.outer_iter_mut() {
            for (x, &m) in sample.iter_mut().zip(self.free.iter()) {
                let noise = sigma * standard_normal(rng);
                *x += m * noise;
            }
        }
    }
}

/// The faces a correction may change, packed (`[2, nx + 1, ny + 1]`): not the
/// padding, not the inflow face, not the side walls' normal faces, not the
/// faces of solid cells, not the viscosity corner.
pub fn free_faces(scene: &Scene) -> ArrayD<f64> {
    let g = scene.grid();
    let solid = scene.solid();
    let (nx, ny) = (g.nx, g.ny);
    let is_solid = |i: Option<usize>, j: Option<usize>| match (i, j) {
        (Some(i), Some(j)) if i < nx && j < ny => solid[[i, j]],
        _ => false,
    };
    let mut m = ArrayD::zeros(vec![2, nx + 1, ny + 1]);
    for a in 1..=nx {
        for b in 0..ny {
            let fixed = is_solid(a.checked_sub(1), Some(b)) || is_solid(Some(a), Some(b));
            m[[0, a, b]] = f64::from(u8::from(!fixed));
        }
    }
    for a in 0..nx {
        for b in 1..ny {
            let fixed = is_solid(Some(a), b.checked_sub(1)) || is_solid(Some(a), Some(b));
            m[[1, a, b]] = f64::from(u8::from(!fixed));
        }
    }
    m
}

/// A variant at a corrector size: what selection on validation chooses among
/// (the typed label of a candidate, printed `sol_4@w16b2`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Entry {
    /// The variant.
    pub variant: Variant,
    /// The corrector's size.
    pub size: NetSize,
}

impl std::fmt::Display for Entry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}@{}", self.variant.name(), self.size.label())
    }
}

/// The corrector's size: a ResNet of `width` channels and `blocks` residual
/// blocks (two 3 × 3 convolutions each).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NetSize {
    /// Channels of the hidden layers.
    pub width: usize,
    /// Residual blocks.
    pub blocks: usize,
}

impl NetSize {
    /// Parses a label `wXbY` (width X, Y blocks).
    ///
    /// # Errors
    /// [`WakeError::Argument`] for anything else or a zero width.
    pub fn parse(label: &str) -> Result<Self> {
        let bad = || WakeError::Argument {
            option: "--capacity-sizes".into(),
            message: format!("not a size wXbY (width X, Y blocks): {label:?}"),
        };
        let (w, b) = label
            .strip_prefix('w')
            .and_then(|r| r.split_once('b'))
            .ok_or_else(bad)?;
        let width: usize = w.parse().map_err(|_| bad())?;
        let blocks: usize = b.parse().map_err(|_| bad())?;
        if width == 0 {
            return Err(bad());
        }
        Ok(NetSize { width, blocks })
    }

    /// A short label, `w16b2`.
    pub fn label(&self) -> String {
        format!("w{}b{}", self.width, self.blocks)
    }
}

/// The corrector: a ResNet on (`u_x`, `u_y`, Re code) over the packed lattice,
/// ReLU, its last layer starting at zero (the hybrid starts as the coarse
/// solver); its output is masked to the [`free_faces`].
pub struct Net {
    stem: Conv2,
    blocks: Vec<(Conv2, Conv2)>,
    head: Conv2,
    free: ArrayD<f64>,
    c_out: usize,
}

impl Net {
    /// A corrector of `size` for `scene` whose convolutions compute in
    /// `arithmetic`, with parameters drawn by `rng`.
    ///
    /// # Errors
    /// [`WakeError::Nn`] for a bad size.
    pub fn new(
        scene: &Scene,
        size: NetSize,
        arithmetic: Arithmetic,
        rng: &mut impl Rng,
    ) -> Result<(Self, Params<f64>)> {
        Self::with_outputs(scene, size, 2, arithmetic, rng)
    }

    /// As [`Net::new`] with `c_out` output channels (2 fit the state; another
    /// count is how a test provokes the shape error).
    ///
    /// # Errors
    /// As [`Net::new`].
    pub fn with_outputs(
        scene: &Scene,
        size: NetSize,
        c_out: usize,
        arithmetic: Arithmetic,
        rng: &mut impl Rng,
    ) -> Result<(Self, Params<f64>)> {
        let mut params = Params::new();
        let conv = |c_in, c_out, init| ConvConfig {
            c_in,
            c_out,
            kernel: 3,
            padding: Padding::Zero,
            init,
        };
        let w = size.width;
        let layer = |params: &mut Params<f64>, name: &str, config, rng: &mut _| {
            Conv2::new(params, name, config, rng).map(|c| c.with_arithmetic(arithmetic))
        };
        let stem = layer(&mut params, "stem", conv(3, w, Init::He), rng)?;
        let blocks = (0..size.blocks)
            .map(|b| {
                Ok((
                    layer(
                        &mut params,
                        &format!("block{b}.a"),
                        conv(w, w, Init::He),
                        rng,
                    )?,
                    layer(
                        &mut params,
                        &format!("block{b}.b"),
                        conv(w, w, Init::He),
                        rng,
                    )?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        let head = layer(&mut params, "head", conv(w, c_out, Init::Zeros), rng)?;
        Ok((
            Net {
                stem,
                blocks,
                head,
                free: free_faces(scene),
                c_out,
            },
            params,
        ))
    }
}

/// `a` repeated along a new leading axis `n` times.
fn repeat(a: &ArrayD<f64>, n: usize) -> ArrayD<f64> {
    let views: Vec<_> = (0..n).map(|_| a.view()).collect();
    ndarray::stack(ndarray::Axis(0), &views).expect("same shapes")
}

impl Corrector for Net {
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        state: Var<'t, f64>,
    ) -> diffphys::tape::Result<Var<'t, f64>> {
        let tape = state.tape();
        let shape = state.shape();
        let (n, a, b) = (shape[0], shape[2], shape[3]);
        if shape[1..] != self.free.shape()[..] {
            return Err(TapeError::shape(
                "wake corrector input",
                self.free.shape(),
                &shape[1..],
            ));
        }
        let free = tape.constant(repeat(&self.free, n));
        // The Re channel is data: read from each sample's viscosity corner.
        let values = state.to_array();
        let mut code = ArrayD::zeros(vec![n, 1, a, b]);
        for k in 0..n {
            let c = re_code(values[[k, 1, a - 1, b - 1]]);
            code.index_axis_mut(ndarray::Axis(0), k).fill(c);
        }
        let x = Var::concat(&[state.mul(free)?, tape.constant(code)], 1)?;
        let mut h = self.stem.forward(p, x)?.relu()?;
        for (c1, c2) in &self.blocks {
            let r = c1.forward(p, h)?.relu()?;
            h = h.add(c2.forward(p, r)?)?.relu()?;
        }
        let out = self.head.forward(p, h)?;
        if self.c_out != 2 {
            return Ok(out);
        }
        out.mul(free)
    }
}

/// The scene's own command-line options (the seeds, `--small`, `--out`,
/// `--iterations` and `--npy` are the examples' common ones).
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// The variants to train (`src` always runs).
    pub variants: Vec<Variant>,
    /// Training Reynolds numbers.
    pub train_re: Vec<f64>,
    /// Validation Reynolds numbers: by default inside the training range
    /// (141, 566) and outside it on both sides (85, 1900), as the held-out
    /// split is.
    pub validation_re: Vec<f64>,
    /// Held-out Reynolds numbers.
    pub held_out_re: Vec<f64>,
    /// Learning rates to choose from on validation.
    pub learning_rates: Vec<f64>,
    /// The corrector sizes of the capacity sweep besides [`MAIN_SIZE`]
    /// (empty: no sweep).
    pub capacity: Vec<NetSize>,
    /// Run the speed study.
    pub speed: bool,
    /// Trainings (and held-out evaluations) run at once, each on its own
    /// thread (default: the available cores).
    pub threads: usize,
    /// The coarse solver's advection (`--coarse-advection`).
    pub coarse_advection: Advection,
    /// How each resolution sees the cylinder (`--body cylinder|staircase|inscribed`).
    pub body: Body,
    /// The reference's scheme (`--reference-scheme second-order|coarse`).
    pub reference: ReferenceScheme,
    /// The corrector's convolution arithmetic (`--network-arithmetic f32|f64`).
    pub arithmetic: Arithmetic,
}

impl Options {
    /// The defaults (full or small).
    pub fn defaults(small: bool) -> Self {
        let list = |v: &[f64]| v.to_vec();
        Options {
            variants: vec![
                Variant::Src,
                Variant::Non,
                Variant::Noise,
                Variant::Sol(4),
                Variant::Sol(16),
            ],
            train_re: if small {
                list(&[200.0, 400.0, 800.0])
            } else {
                list(&[100.0, 200.0, 400.0, 800.0, 1600.0])
            },
            validation_re: if small {
                list(&[566.0])
            } else {
                list(&[85.0, 141.0, 566.0, 1900.0])
            },
            held_out_re: if small {
                list(&[283.0, 2263.0])
            } else {
                list(&[71.0, 283.0, 1131.0, 2263.0])
            },
            learning_rates: if small { vec![1e-3] } else { vec![1e-3, 3e-3] },
            capacity: vec![SIZES[0], SIZES[2]],
            speed: true,
            threads: std::thread::available_parallelism().map_or(1, usize::from),
            coarse_advection: Advection::SemiLagrangian,
            body: Body::Inscribed,
            reference: ReferenceScheme::SecondOrder,
            arithmetic: Arithmetic::Single,
        }
    }

    /// The unrolls of the SOL variants, in order.
    pub fn unrolls(&self) -> Vec<usize> {
        self.variants
            .iter()
            .filter_map(|v| match v {
                Variant::Sol(k) => Some(*k),
                _ => None,
            })
            .collect()
    }

    /// Whether `re` lies inside the training range.
    pub fn inside(&self, re: f64) -> bool {
        let lo = self.train_re.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = self
            .train_re
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        (lo..=hi).contains(&re)
    }
}

/// The corrector sizes of the capacity sweep (about 1.5k, 10k and 22k
/// parameters); the middle one is the main variants' size.
pub const SIZES: [NetSize; 3] = [
    NetSize {
        width: 8,
        blocks: 1,
    },
    NetSize {
        width: 16,
        blocks: 2,
    },
    NetSize {
        width: 24,
        blocks: 2,
    },
];

/// The main variants' corrector size.
pub const MAIN_SIZE: NetSize = SIZES[1];
