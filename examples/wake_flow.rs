//! The hybrid wake-flow solver: a coarse flow solver (32 × 64 cells) with a
//! corrector network trained through it against a 4× finer reference, tested
//! at Reynolds numbers it never saw, and set against simply running a finer
//! grid.
//!
//! Scene (physics in `wake_flow_scene`): a cylinder wake in a 2 × 1 channel,
//! uniform inflow, outflow, free-slip side walls; the coarse solver is
//! semi-Lagrangian with plain splitting, the reference 128 × 256 with
//! MacCormack and incremental splitting, restricted by face averages.
//!
//! Variants, each trained with the same budget of corrector evaluations:
//! `src` (uncorrected), `non` (one-step pairs), `noise` (`non` with input
//! noise), `sol_4` and `sol_16` (through 4 and 16 coarse steps, gradients
//! through the pressure solve; `sol_16` checkpointed every 4 steps). The
//! learning rate (pilot runs), the unroll and the stopping iteration are chosen
//! on the validation Reynolds numbers; each trained model is evaluated once on
//! the held-out ones. A capacity sweep trains `non` and `sol_4` at three
//! corrector sizes. The speed study rolls out the uncorrected solver at 1×, 2×
//! and 4× the resolution and the corrected coarse one, timed.
//!
//! Options: `wake_flow --help` lists every flag with its default (the scene's
//! own in `wake_flow_scene::cli`). Every trained corrector is saved under
//! `OUT/models/` with the settings that shaped it; `wake_flow evaluate
//! --model DIR --held-out-re LIST` evaluates one at any Re in range without
//! training; `wake_flow convergence` sets the reference against the same
//! scheme one level finer. Tutorial: docs/11-wake-flow.md. Run:
//! `cargo run --release --example wake_flow` (`-- --small` for CI).

mod common;
#[path = "wake_flow_scene/phases.rs"]
mod phases;
#[path = "wake_flow_scene/report.rs"]
mod report;
mod wake_flow_scene;

use std::time::Instant;

use diffphys::flow::PressureSolver;
use diffphys::hybrid::reference::Reference;
use diffphys::hybrid::study::{Probe, Record, Setup};
use diffphys::hybrid::wake::{self, Wake};
use diffphys::learn::{Hybrid, LrSchedule, ModelCard, Splits, TrainSeed};
use diffphys::nn::{Arithmetic, Params};
use serde_json::{json, Value};

use diffphys::learn::cache::Cache;
use phases::{references, speed_study};
use report::report;
use wake_flow_scene::cli::{self, Cli, Command, ConvergenceArgs, EvaluateArgs};
use wake_flow_scene::{
    net, re_code, Body, Coarse, Net, NetSize, Options, Variant, CHANNEL, MAIN_SIZE, SIZES,
    STEP_EVALUATIONS,
};

type BoxError = Box<dyn std::error::Error + Send + Sync>;
type Hybrids = Hybrid<Coarse, Net>;

/// Corrector evaluations per training at full size (each variant's Adam steps
/// are this over its evaluations per step). Chosen on validation and on the
/// hour the scene may take: at 24,000, 9 of the 15 main trainings still
/// improved on validation at their last step and the scene took 34 minutes;
/// 36,000 took 66 minutes with the corrector in `f64`; 48,000 with it in `f32`
/// (about 1.3× faster) fills about the hour again (docs/11).
const EVALUATIONS: usize = 48_000;

/// A learning-rate pilot trains on the budget divided by this (a quarter,
/// first training seed).
const PILOT_DIVISOR: usize = 4;

/// Validate (for early stopping) every this many corrector evaluations at
/// full size.
const VALIDATION_EVALUATIONS: usize = 1_600;

/// `wake_flow evaluate --model DIR [--held-out-re LIST] [--data-seed N]`
/// with the scene's options: a saved corrector rolled out at each Re.
fn evaluate_command(e: EvaluateArgs) -> Result<(), BoxError> {
    let run_start = Instant::now();
    let small = e.scene.small;
    let options = e.scene.options()?;
    let out = e.scene.out();
    let scene = wake_flow_scene::wake(&options, small);
    println!(
        "wake flow: evaluating {} at Re {:?} ({} x {} coarse cells)",
        e.model.display(),
        options.held_out_re,
        scene.sizes.ny,
        scene.sizes.nx
    );
    // The error's own message (a mismatch names the field), not its debug form.
    let result = scene
        .evaluate(&wake::Evaluation {
            model: &e.model,
            code: re_code,
            arithmetic: options.arithmetic,
            re: &options.held_out_re,
            data_seed: e.data_seed,
            out: &out,
            threads: options.threads,
        })
        .map_err(|e| e.to_string())?;
    common::print_json_line(&json!({
        "example": "wake_flow",
        "command": "evaluate",
        "small": small,
        "evaluation": result,
        "peak_rss_bytes": common::peak_rss_bytes(),
        "wall_s": run_start.elapsed().as_secs_f64(),
    }));
    let count = |k: &str| result.get(k).and_then(serde_json::Value::as_u64);
    if count("identical_to_training") != count("compared_with_training") {
        return Err(
            "the reloaded corrector's figures differ from those of the run that trained it".into(),
        );
    }
    Ok(())
}

/// `wake_flow convergence [--data-seed N]` with the scene's options.
fn convergence_command(c: ConvergenceArgs) -> Result<(), BoxError> {
    let run_start = Instant::now();
    let options = c.scene.options()?;
    let re = [
        &options.train_re,
        &options.validation_re,
        &options.held_out_re,
    ];
    let scene = wake_flow_scene::wake(&options, c.scene.small);
    let result = scene.convergence(re.map(|r| &r[..]), c.data_seed, options.threads)?;
    common::print_json_line(&json!({
        "example": "wake_flow",
        "command": "convergence",
        "small": c.scene.small,
        "convergence": result,
        "peak_rss_bytes": common::peak_rss_bytes(),
        "wall_s": run_start.elapsed().as_secs_f64(),
    }));
    Ok(())
}

/// What every phase of the study reads: the options, the scenes, the cache.
struct Ctx {
    options: Options,
    wake: Wake,
    seeds: common::Seeds,
    args: common::ExampleArgs,
    coarse: Coarse,
    fine: diffphys::flow::Scene,
    cache: Cache,
    /// The budget of each training: corrector evaluations.
    evaluations: usize,
    threads: usize,
    arithmetic: Arithmetic,
    /// Develop on validation only (`--validation-only`): the held-out split
    /// is not read.
    validation_only: bool,
}

impl Ctx {
    fn new(cli: &Cli) -> Result<Self, BoxError> {
        let small = cli.train.scene.small;
        let options = Options::from_args(&cli.train)?;
        let (data, train) = cli::seeds(&cli.train)?;
        let args = common::ExampleArgs {
            small,
            out: cli.train.scene.out(),
            npy: cli.train.npy,
        };
        std::fs::create_dir_all(&args.out)?;
        let wake = wake_flow_scene::wake(&options, small);
        let fine = wake.reference_scene()?;
        let coarse = Coarse::new(wake.uncorrected(1, PressureSolver::Cholesky)?);
        let cache = wake.cache(&args.out)?;
        let sizes = &wake.sizes;
        // `--iterations N`: N Adam steps of STEP_EVALUATIONS evaluations each.
        let evaluations = cli
            .train
            .iterations
            .map_or(args.pick(EVALUATIONS, 16 * STEP_EVALUATIONS), |n| {
                n * STEP_EVALUATIONS
            });
        println!(
            "wake flow: coarse {} x {} (dt {}), reference {} x {} (dt {}); train Re {:?}, validation Re {:?}, held-out Re {:?}; {} corrector evaluations per training, at least {} per Adam step",
            sizes.ny, sizes.nx, sizes.dt, fine.grid().ny, fine.grid().nx, fine.dt(),
            options.train_re, options.validation_re, options.held_out_re, evaluations, STEP_EVALUATIONS
        );
        Ok(Ctx {
            threads: options.threads,
            arithmetic: options.arithmetic,
            options,
            wake,
            seeds: common::Seeds { data, train },
            args,
            coarse,
            fine,
            cache,
            evaluations,
            validation_only: cli.train.validation_only,
        })
    }

    /// The study of the scene's options (see [`Setup`]); `card` gives the
    /// settings a saved corrector of a size must match.
    fn setup<'a>(&'a self, card: &'a (dyn Fn(NetSize) -> ModelCard + Sync)) -> Setup<'a> {
        let (options, sizes) = (&self.options, &self.wake.sizes);
        Setup {
            coarse: &self.coarse,
            code: wake_flow_scene::re_code,
            arithmetic: self.arithmetic,
            variants: &options.variants,
            main_size: MAIN_SIZE,
            capacity: &options.capacity,
            learning_rates: &options.learning_rates,
            train_seeds: &self.seeds.train,
            evaluations: self.evaluations,
            step_evaluations: STEP_EVALUATIONS,
            pilot_divisor: PILOT_DIVISOR,
            validation_evaluations: self.args.pick(VALIDATION_EVALUATIONS, 32),
            schedule: LrSchedule::Cosine {
                final_fraction: 0.1,
            },
            checkpoint: Some(4),
            evaluation: self.wake.evaluation(),
            held_out_conditions: options.held_out_re.len(),
            threads: self.threads,
            validation_only: self.validation_only,
            models: self.args.out.join("models"),
            card,
            // The staircase and inscribed bodies make the pinned faces'
            // error zero by construction.
            pinned_must_vanish: (sizes.body != Body::Cylinder).then(|| sizes.body.label()),
        }
    }

    /// A corrector of `size` on the coarse scene, drawn from training seed
    /// `seed`.
    fn new_net(&self, size: NetSize, seed: u64) -> wake_flow_scene::Result<(Net, Params<f64>)> {
        net(
            self.coarse.scene(),
            size,
            self.arithmetic,
            &mut TrainSeed(seed).init_rng(),
        )
    }
}

fn main() -> Result<(), BoxError> {
    let run_start = Instant::now();
    let cli: Cli = common::parse_args("wake_flow")?;
    match cli.command {
        Some(Command::Evaluate(e)) => return evaluate_command(e),
        Some(Command::Convergence(c)) => return convergence_command(c),
        None => {}
    }
    let ctx = Ctx::new(&cli)?;
    let mut rec = Record::default();
    let card = |size| ctx.wake.card(size, ctx.arithmetic);
    let setup = ctx.setup(&card);
    let mut speed_inputs = None;
    let mut params_count = serde_json::Map::new();
    for size in std::iter::once(MAIN_SIZE).chain(ctx.options.capacity.iter().copied()) {
        let (_, p) = ctx.new_net(size, 0)?;
        params_count.insert(size.label(), json!(p.count()));
    }
    for &ds in &ctx.seeds.data {
        let splits = references(&ctx, ds)?;
        let (train, validation, sigma) = setup.untrained(ds, &splits, &mut rec)?;
        mem("src");
        let probe = setup.protocol(ds, &splits, (&train, &validation), sigma, &mut rec)?;
        mem("held-out");
        if speed_inputs.is_none() {
            speed_inputs = Some((splits, probe));
        }
    }
    let speed = speed_study(&ctx, speed_inputs.as_ref(), &mut rec)?;
    count_readings(&ctx, &mut rec)?;
    report(&ctx, rec, speed, params_count, run_start)
}

/// Appends this run's held-out readings to the output folder's ledger: per
/// data seed, the split (the reference's settings, the held-out Re, the seed)
/// and the configuration that shaped the models read on it (every option but
/// the held-out Re, the thread count and the speed study; the budget; the
/// training seeds).
fn count_readings(ctx: &Ctx, rec: &mut Record) -> Result<(), BoxError> {
    let shaping = Options {
        held_out_re: Vec::new(),
        threads: 0,
        speed: false,
        ..ctx.options.clone()
    };
    let configuration = format!(
        "{shaping:?} | {:?} | corrector evaluations {} | training seeds {:?}",
        ctx.wake.sizes, ctx.evaluations, ctx.seeds.train
    );
    let split = |ds| {
        format!(
            "{} | held-out Re {:?} | data seed {ds}",
            ctx.cache.settings(),
            ctx.options.held_out_re
        )
    };
    Ok(rec
        .log
        .count_readings(&ctx.args.out, split, &configuration)?)
}

/// Prints the peak resident memory so far (the tapes' buffer pools are freed
/// with the training runs that made them).
fn mem(phase: &str) {
    println!(
        "  memory after {phase}: peak RSS {:.0} MB",
        common::peak_rss_bytes().unwrap_or(0) as f64 / 1e6
    );
}
