//! The scene of `wake_flow`: its channel, sizes, default options and
//! corrector sizes; the hybrid library's [`diffphys::hybrid::wake`] builds
//! the solvers, the reference and the study from them.
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
//! - reference: 8× finer in space and time at full size (256 × 512, `dt / 8`,
//!   [`FULL_REFERENCE_FACTOR`]; 4× at `--small`), MacCormack
//!   advection with the limiter and incremental (second-order) splitting,
//!   restricted to the coarse grid by face averages
//!   ([`diffphys::flow::restrict_velocity`]);
//! - uncorrected finer solvers for the speed study: the coarse scheme at 2×
//!   and 4× the resolution (`dt / 2`, `dt / 4`).
//!
//! A coarse state is its fields (`u_x`, `u_y`) with its viscosity as the
//! sample's parameter ([`diffphys::flow::batch`]), so one batch mixes
//! Reynolds numbers.

pub use diffphys::hybrid::wake::args::{Options, SceneArgs, TrainArgs};
pub use diffphys::hybrid::wake::{Body, Channel, ReferenceScheme, Sizes, Wake};
use diffphys::hybrid::NetSize;
pub use diffphys::learn::study::Variant;

use diffphys::flow::{Advection, Splitting};
use diffphys::nn::Arithmetic;

/// The scene's channel: 2 long and 1 wide, a cylinder of diameter 0.2 at
/// (0.5, 0.5), inflow speed 1, a reference 4× finer in space and time
/// (`--reference-factor` refines it; the inscribed body stays that of 4×),
/// Re from 50 to 3200, the scenes built at Re 400.
pub const CHANNEL: Channel = Channel {
    extent: [2.0, 1.0],
    centre: [0.5, 0.5],
    diameter: 0.2,
    inflow: 1.0,
    factor: 4,
    inscribed_at: 4,
    re_range: [50.0, 3200.0],
    re_centre: RE_CENTRE,
};

/// The full scene's reference factor: 256 × 512, the level whose own error
/// the 2×/4×/8× observed order shows to be a tenth of the corrected error or
/// less at the held-out Re (docs/11, "Narrowed before the final run");
/// `--small` keeps the channel's 4×.
pub const FULL_REFERENCE_FACTOR: usize = 8;

/// The Reynolds number the network's Re channel is centred on.
pub const RE_CENTRE: f64 = 400.0;

/// The scene's result type: the hybrid library's errors.
pub type Result<T> = std::result::Result<T, diffphys::hybrid::HybridError>;

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

/// The typed options of the study's command line: [`defaults`] with the
/// flags applied.
///
/// # Errors
/// As [`Options::from_args`].
pub fn options(args: &TrainArgs) -> Result<Options> {
    Options::from_args(args, &CHANNEL, defaults(args.scene.small), MAIN_SIZE)
}

/// The scene's options for `evaluate` and `convergence`: [`defaults`] with
/// the scene's flags applied.
///
/// # Errors
/// As [`SceneArgs::options`].
pub fn scene_options(args: &SceneArgs) -> Result<Options> {
    args.options(&CHANNEL, defaults(args.small))
}

/// The scene of `options` (full or small).
pub fn wake(options: &Options, small: bool) -> Wake {
    Wake {
        channel: Channel {
            factor: options.reference_factor,
            ..CHANNEL
        },
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

/// The scene's defaults (full or small): the splits' Reynolds numbers, the
/// variants, the learning rates to pilot, the capacity sweep's sizes.
pub fn defaults(small: bool) -> Options {
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
            // The first validation set, then the spent held-out split of
            // data seed 1's runs (docs/11, "The new held-out split").
            list(&[85.0, 141.0, 566.0, 1900.0, 71.0, 283.0, 1131.0, 2263.0])
        },
        held_out_re: if small {
            list(&[283.0, 2263.0])
        } else {
            // Pre-registered on 2026-11-29 (docs/11) as 65, 250, 1000 and
            // 2100; narrowed on 2026-12-08, before any reading, to the two
            // where the reference's scheme is shown converged over a
            // rollout. Read once, by the final configuration.
            list(&[65.0, 250.0])
        },
        learning_rates: if small { vec![1e-3] } else { vec![1e-3, 3e-3] },
        capacity: vec![SIZES[0], SIZES[2]],
        speed: true,
        threads: std::thread::available_parallelism().map_or(1, usize::from),
        coarse_advection: Advection::SemiLagrangian,
        coarse_splitting: Splitting::Plain,
        body: Body::Inscribed,
        reference: ReferenceScheme::SecondOrder,
        reference_factor: if small {
            CHANNEL.factor
        } else {
            FULL_REFERENCE_FACTOR
        },
        arithmetic: Arithmetic::Single,
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
