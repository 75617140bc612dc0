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
//!   splitting (`--coarse-splitting incremental`: second-order, the state
//!   then carries the pressure), sparse Cholesky pressure solve, `dt` = 0.01 (Courant 0.32 at
//!   the inflow speed);
//! - reference: 4× finer in space and time (128 × 256, `dt / 4`), MacCormack
//!   advection with the limiter and incremental (second-order) splitting,
//!   restricted to the coarse grid by face averages
//!   ([`diffphys::flow::restrict_velocity`]);
//! - uncorrected finer solvers for the speed study: the coarse scheme at 2×
//!   and 4× the resolution (`dt / 2`, `dt / 4`).
//!
//! A coarse state is its fields (`u_x`, `u_y`) with its viscosity as the
//! sample's parameter ([`diffphys::flow::batch`]), so one batch mixes
//! Reynolds numbers.

pub mod cli;
mod net;

pub use diffphys::hybrid::wake::{Body, Channel, ReferenceScheme, Sizes, Wake};
pub use diffphys::hybrid::NetSize;
pub use diffphys::learn::study::Variant;
pub use net::{net, Net, MAIN_SIZE, SIZES};

/// The coarse solver: the hybrid library's simulator of the coarse scene (a
/// viscosity per sample, so one batch mixes Reynolds numbers).
pub type Coarse = diffphys::hybrid::FlowSimulator;

use diffphys::flow::{Advection, FlowError, Splitting};
use diffphys::learn::{LearnError, Split};
use diffphys::nn::{Arithmetic, NnError};
use diffphys::tape::TapeError;

/// The scene's channel: 2 long and 1 wide, a cylinder of diameter 0.2 at
/// (0.5, 0.5), inflow speed 1, a reference 4× finer in space and time,
/// Re from 50 to 3200, the scenes built at Re 400.
pub const CHANNEL: Channel = Channel {
    extent: [2.0, 1.0],
    centre: [0.5, 0.5],
    diameter: 0.2,
    inflow: 1.0,
    factor: 4,
    re_range: [50.0, 3200.0],
    re_centre: RE_CENTRE,
};

/// The Reynolds number the network's Re channel is centred on.
pub const RE_CENTRE: f64 = 400.0;

/// Everything that can go wrong in the scene.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WakeError {
    /// A bad command-line argument.
    #[error("{option}: {message}")]
    Argument {
        /// The option.
        option: String,
        /// What is wrong.
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
    /// The hybrid library refused (a Reynolds number out of range, a
    /// corrector size, a trajectory).
    #[error(transparent)]
    Hybrid(#[from] diffphys::hybrid::HybridError),
}

/// The scene's result type.
pub type Result<T> = std::result::Result<T, WakeError>;

/// The network's Re input: `ln(Re / RE_CENTRE) / ln 4`, about −1.5 to 1.5
/// over the channel's range.
pub fn re_code(nu: f64) -> f64 {
    let re = CHANNEL.inflow * CHANNEL.diameter / nu;
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

/// A comma-separated list of Reynolds numbers, each checked.
///
/// # Errors
/// [`WakeError::Argument`] for text that is not a number;
/// [`diffphys::hybrid::HybridError::ReOutOfRange`]; [`LearnError::EmptySplit`] for an empty list.
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
        .map(|r| r.and_then(|re| Ok(CHANNEL.checked_re(re)?)))
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

/// The scene of `options` (full or small).
pub fn wake(options: &Options, small: bool) -> Wake {
    Wake {
        channel: CHANNEL,
        sizes: Sizes {
            advection: options.coarse_advection,
            splitting: options.coarse_splitting,
            body: options.body,
            reference: options.reference,
            ..if small { small_sizes() } else { full_sizes() }
        },
    }
}

/// The full scene: 32 × 64 coarse cells, dt 0.01.
pub fn full_sizes() -> Sizes {
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
        splitting: Splitting::Plain,
        body: Body::Inscribed,
        reference: ReferenceScheme::SecondOrder,
    }
}

/// CI: 16 × 32 cells, short trajectories.
pub fn small_sizes() -> Sizes {
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
        ..full_sizes()
    }
}

pub use diffphys::hybrid::wake::{ADVECTIONS, ARITHMETICS, SPLITTINGS};

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
    /// The coarse solver's splitting (`--coarse-splitting`).
    pub coarse_splitting: Splitting,
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
            coarse_splitting: Splitting::Plain,
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
