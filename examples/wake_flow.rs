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
//! training. Tutorial: docs/11-wake-flow.md. Run:
//! `cargo run --release --example wake_flow` (`-- --small` for CI).

mod common;
mod wake_flow_scene;

use std::collections::BTreeMap;
use std::time::Instant;

use diffphys::flow::PressureSolver;
use diffphys::learn::study::{pilot_learning_rates, run_jobs, select_groups, Group, Plan};
use diffphys::learn::{
    rollout, Budget, DataSeed, Hybrid, LrSchedule, Report, SavedModel, Schedule, Simulator, Split,
    Splits, Strategy, TrainSeed, Trained, TrainedCorrector, Trainer, Trajectory,
};
use diffphys::nn::{Arithmetic, Params};
use diffphys_compare::harness::progress_bar;
use ndarray::Array3;
use serde_json::{json, Value};

use clap::Parser;
use wake_flow_scene::cli::{self, Cli, Command, EvaluateArgs};
use wake_flow_scene::data::{base_state, reference, Bump, Cache, Reference};
use wake_flow_scene::model;
use wake_flow_scene::study::{self, HeldOutRun};
use wake_flow_scene::{
    free_faces, reference_scene, uncorrected, Body, Coarse, Entry, Net, NetSize, Options, Sizes,
    Variant, WakeError, MAIN_SIZE, SIZES, STEP_EVALUATIONS,
};

type BoxError = Box<dyn std::error::Error>;
type Wake = Hybrid<Coarse, Net>;

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

fn strategy(variant: Variant, sigma: f64) -> Option<Strategy> {
    match variant {
        Variant::Src => None,
        Variant::Non => Some(Strategy::NonInteracting),
        Variant::Noise => Some(Strategy::Noise { sigma }),
        Variant::Sol(unroll) => Some(Strategy::SolverInTheLoop {
            unroll,
            schedule: if unroll > 4 {
                Schedule::Every(4)
            } else {
                Schedule::Full
            },
        }),
    }
}

/// `count` states from `start` of a reference, as a trajectory.
fn window(r: &Reference, start: usize, count: usize) -> Trajectory {
    r.states[start..start + count]
        .iter()
        .map(|s| s.clone().into_dyn())
        .collect()
}

/// The root mean square one-step error of the coarse solver over the free
/// faces of the training trajectories (every 10th state): the noise scale.
fn one_step_rms(coarse: &Coarse, train: &[Trajectory]) -> Result<f64, BoxError> {
    let free = free_faces(&coarse.scene);
    let (mut sum, mut count) = (0.0, 0.0);
    for tr in train {
        for t in (0..tr.len() - 1).step_by(10) {
            let batch = tr[t].clone().insert_axis(ndarray::Axis(0));
            let next = coarse.step_plain(&batch)?;
            let d = (&next.index_axis(ndarray::Axis(0), 0) - &tr[t + 1]) * &free;
            sum += d.mapv(|e| e * e).sum();
            count += free.sum();
        }
    }
    Ok((sum / count).sqrt())
}

struct Model {
    variant: Variant,
    size: NetSize,
    seed: u64,
    lr: f64,
    evaluations: usize,
    trained: Trained<TrainedCorrector>,
    seconds: f64,
    /// The kept parameters' validation error at each validation Re.
    validation_per_re: Vec<f64>,
}

/// One training: a variant at a corrector size, a training seed, a learning
/// rate and an iteration count.
#[derive(Debug, Clone, Copy)]
struct Job {
    variant: Variant,
    size: NetSize,
    seed: u64,
    lr: f64,
    /// The budget: corrector evaluations.
    evaluations: usize,
}

/// What every training shares (each job's budget, steps and learning rate
/// come from its [`Job`]).
struct Setup<'a> {
    /// How the learning rate changes over a training.
    schedule: LrSchedule,
    /// Steps of the validation rollouts.
    validation_steps: usize,
    /// Validate every this many corrector evaluations.
    validation_evaluations: usize,
    coarse: &'a Coarse,
    /// The corrector's convolution arithmetic.
    arithmetic: Arithmetic,
    sigma: f64,
    data_seed: u64,
    train: &'a [Trajectory],
    validation: &'a [Trajectory],
}

fn train_one(setup: &Setup<'_>, job: &Job) -> Result<Model, BoxError> {
    let Job {
        variant,
        size,
        seed,
        lr,
        evaluations,
    } = *job;
    let per_step = variant.step_evaluations();
    let iterations = variant.adam_steps(evaluations);
    let trainer = Trainer {
        learning_rate: lr,
        budget: Budget {
            iterations,
            evaluations_per_iteration: per_step,
        },
        schedule: setup.schedule,
        validate_every: (setup.validation_evaluations / per_step).max(1),
        validation_steps: setup.validation_steps,
    };
    let strategy = strategy(variant, setup.sigma).ok_or("src is not trained")?;
    let (net, params) = Net::new(
        &setup.coarse.scene,
        size,
        setup.arithmetic,
        &mut TrainSeed(seed).init_rng(),
    )?;
    let hybrid = Hybrid::new(setup.coarse.clone(), net);
    let bar = progress_bar(
        iterations,
        &format!(
            "data {} {:>6} {} seed {seed} (lr {lr:.0e})",
            setup.data_seed,
            variant.name(),
            size.label(),
        ),
    );
    let start = Instant::now();
    let trained = trainer.train(
        &hybrid,
        params,
        strategy,
        setup.train,
        setup.validation,
        TrainSeed(seed),
        &|| bar.inc(1),
    )?;
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let validation_per_re = per_trajectory(
        &hybrid,
        Some(&trained.model.params),
        setup.validation,
        setup.validation_steps,
    )?;
    println!(
        "  {:>6} {} seed {seed}, lr {lr:.0e}: {:.1} s, validation {:.5} (kept iteration {} of {iterations}; per Re {})",
        variant.name(),
        size.label(),
        seconds,
        trained.model.validation,
        trained.model.best_iteration,
        validation_per_re
            .iter()
            .map(|e| format!("{e:.4}"))
            .collect::<Vec<_>>()
            .join(", "),
    );
    Ok(Model {
        variant,
        size,
        seed,
        lr,
        evaluations,
        trained,
        seconds,
        validation_per_re,
    })
}

/// The rollout error on each trajectory on its own (the validation split
/// holds one per Reynolds number).
fn per_trajectory(
    hybrid: &Wake,
    params: Option<&Params<f64>>,
    trajectories: &[Trajectory],
    steps: usize,
) -> Result<Vec<f64>, BoxError> {
    trajectories
        .iter()
        .map(|t| Ok(rollout(hybrid, params, std::slice::from_ref(t), steps)?.mean()))
        .collect()
}

/// `wake_flow evaluate --model DIR [--held-out-re LIST] [--data-seed N]`
/// with the scene's options: a saved corrector rolled out at each Re.
fn evaluate_command(e: EvaluateArgs) -> Result<(), BoxError> {
    let run_start = Instant::now();
    let small = e.scene.small;
    let options = e.scene.options()?;
    let out = e.scene.out();
    let sizes = Sizes::of(&options, small);
    println!(
        "wake flow: evaluating {} at Re {:?} ({} x {} coarse cells)",
        e.model.display(),
        options.held_out_re,
        sizes.ny,
        sizes.nx
    );
    // The error's own message (a mismatch names the field), not its debug form.
    let result = model::evaluate(&model::Evaluation {
        model: &e.model,
        sizes: &sizes,
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

/// What every phase of the study reads: the options, the scenes, the cache.
struct Ctx {
    options: Options,
    sizes: Sizes,
    seeds: common::Seeds,
    args: common::ExampleArgs,
    coarse: Coarse,
    fine: diffphys::flow::Scene,
    cache: Cache,
    /// The budget of each training: corrector evaluations.
    evaluations: usize,
    threads: usize,
    arithmetic: Arithmetic,
}

impl Ctx {
    fn new(cli: &Cli) -> Result<Self, BoxError> {
        let small = cli.train.scene.small;
        let options = Options::from_args(&cli.train)?;
        let (data, train) = cli::seeds(&cli.train)?;
        let args = common::ExampleArgs {
            small,
            out: cli.train.scene.out(),
            iterations: cli.train.iterations,
            npy: cli.train.npy,
        };
        std::fs::create_dir_all(&args.out)?;
        let sizes = Sizes::of(&options, small);
        let fine = reference_scene(&sizes)?;
        let coarse = Coarse::new(uncorrected(&sizes, 1, PressureSolver::Cholesky)?);
        let cache = Cache::new(&args.out, &sizes)?;
        // `--iterations N`: N Adam steps of STEP_EVALUATIONS evaluations each.
        let evaluations = args
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
            sizes,
            seeds: common::Seeds { data, train },
            args,
            coarse,
            fine,
            cache,
            evaluations,
        })
    }

    /// A corrector of `size` on the coarse scene, drawn from training seed
    /// `seed`.
    fn new_net(&self, size: NetSize, seed: u64) -> wake_flow_scene::Result<(Net, Params<f64>)> {
        Net::new(
            &self.coarse.scene,
            size,
            self.arithmetic,
            &mut TrainSeed(seed).init_rng(),
        )
    }
}

/// The trained groups of one data seed: a variant and its runs, one per
/// training seed.
type Groups = Vec<(Variant, Vec<Model>)>;

/// The selected SOL corrector of the first data seed: its parameters and size.
type Probe = (Params<f64>, NetSize);

/// What the phases record for the report.
#[derive(Default)]
struct Record {
    results: Results,
    validation_report: Report,
    selected_k: serde_json::Map<String, Value>,
    selected_size: serde_json::Map<String, Value>,
    chosen_lr: serde_json::Map<String, Value>,
    capacity_runs: Vec<(NetSize, Variant, u64, f64, f64, usize)>,
    train_seconds: BTreeMap<String, Vec<f64>>,
    /// Per training: its validation curve and the iteration early stopping kept.
    validation_curves: BTreeMap<String, Value>,
    /// Variant → validation Re → the error of every training (main size).
    validation_per_re: BTreeMap<String, BTreeMap<String, Vec<f64>>>,
    sigma_used: f64,
    pinned_face_error: serde_json::Map<String, Value>,
    /// How often each data seed's held-out split was read (each trained model
    /// once; the baselines: src, the reference's last state, the speed study).
    held_out_readings: serde_json::Map<String, Value>,
}

fn main() -> Result<(), BoxError> {
    let run_start = Instant::now();
    let cli = Cli::parse();
    if let Some(Command::Evaluate(e)) = cli.command {
        return evaluate_command(e);
    }
    let ctx = Ctx::new(&cli)?;
    let mut rec = Record::default();
    let mut speed_inputs = None;
    let mut params_count = serde_json::Map::new();
    for size in std::iter::once(MAIN_SIZE).chain(ctx.options.capacity.iter().copied()) {
        let (_, p) = ctx.new_net(size, 0)?;
        params_count.insert(size.label(), json!(p.count()));
    }
    for &ds in &ctx.seeds.data {
        let splits = references(&ctx, ds)?;
        let (train, validation, sigma) = untrained(&ctx, ds, &splits, &mut rec)?;
        let trained = train_variants(&ctx, ds, (&train, &validation), sigma, &mut rec)?;
        let probe = select_and_evaluate(&ctx, ds, &splits, trained, &mut rec)?;
        if speed_inputs.is_none() {
            speed_inputs = Some((splits, probe));
        }
    }
    let speed = speed_study(&ctx, speed_inputs.as_ref(), &mut rec)?;
    report(&ctx, rec, speed, params_count, run_start)
}

/// Phase 1: the three splits of data seed `ds`, the reference generated or
/// read from the cache.
fn references(ctx: &Ctx, ds: u64) -> Result<Splits<Vec<Reference>>, BoxError> {
    let Ctx {
        options,
        sizes,
        coarse,
        fine,
        cache,
        ..
    } = ctx;
    let threads = ctx.threads;
    // Phase 1: the reference (cached).
    let total = 3 * sizes.warm_base
        + (options.train_re.len() + options.validation_re.len() + options.held_out_re.len())
            * (sizes.warm + sizes.record);
    let bar = progress_bar(total, &format!("data {ds}: reference"));
    let t0 = Instant::now();
    let splits = Splits::generate(
        DataSeed(ds),
        [
            options.train_re.len(),
            options.validation_re.len(),
            options.held_out_re.len(),
        ],
        |split, _, rng| {
            let list = match split {
                Split::Train => &options.train_re,
                Split::Validation => &options.validation_re,
                Split::HeldOut => &options.held_out_re,
            };
            let mut run = || -> Result<Vec<Reference>, BoxError> {
                let bump = Bump::draw(rng);
                let tick = |n| bar.inc(n);
                let base = base_state(cache, sizes, fine, bump, &tick)?;
                // The Reynolds numbers of a split share the workers.
                Ok(run_jobs(list, threads, |&re| {
                    reference(cache, sizes, &coarse.scene, fine, (&base, bump), re, &tick)
                        .map_err(|e| e.to_string())
                })?)
            };
            run().map_err(|e| diffphys::learn::LearnError::Invalid {
                what: "reference",
                message: e.to_string(),
            })
        },
    )?;
    bar.finish_and_clear();
    mem("reference");
    println!(
        "data seed {ds}: reference ready in {:.1} s (cached under {})",
        t0.elapsed().as_secs_f64(),
        cache.dir.display()
    );
    Ok(splits)
}

/// The training and validation trajectories of data seed `ds`, the noise
/// scale, the error on the faces the coarse step pins, and `src`'s validation.
fn untrained(
    ctx: &Ctx,
    ds: u64,
    splits: &Splits<Vec<Reference>>,
    rec: &mut Record,
) -> Result<(Vec<Trajectory>, Vec<Trajectory>, f64), BoxError> {
    let Ctx {
        options,
        sizes,
        coarse,
        ..
    } = ctx;
    let Record {
        validation_report,
        validation_per_re,
        sigma_used,
        pinned_face_error,
        ..
    } = rec;
    let new_net = |size, seed| ctx.new_net(size, seed);
    let train: Vec<Trajectory> = splits
        .train
        .iter()
        .map(|r| window(r, 0, r.states.len()))
        .collect();
    let validation: Vec<Trajectory> = splits
        .validation
        .iter()
        .flat_map(|r| [0].into_iter().map(|s| window(r, s, sizes.rollout + 1)))
        .collect();
    let sigma = one_step_rms(coarse, &train)?;
    // What no corrector can remove: the pinned faces' error (train and
    // validation Re; the body decides it, see `Body`).
    let free = free_faces(&coarse.scene);
    let mut pinned = Vec::new();
    for (re, t) in options
        .train_re
        .iter()
        .zip(&train)
        .chain(options.validation_re.iter().zip(&validation))
    {
        pinned.push((*re, study::pinned_face_error(coarse, &free, t)?));
    }
    println!(
        "  error on the faces the coarse step pins (no corrector removes it), per train and validation Re: {}",
        pinned
            .iter()
            .map(|(re, e)| format!("{re}: {e:.4}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    // The staircase and inscribed bodies make this zero by construction.
    if sizes.body != Body::Cylinder {
        if let Some(&(re, error)) = pinned.iter().find(|(_, e)| *e > 1e-12) {
            return Err(WakeError::PinnedFaces {
                body: sizes.body.label(),
                re,
                error,
            }
            .into());
        }
    }
    pinned_face_error.insert(
        format!("data_{ds}"),
        pinned
            .iter()
            .map(|(re, e)| (re.to_string(), json!(e)))
            .collect(),
    );
    *sigma_used = sigma;
    let (net0, _) = new_net(MAIN_SIZE, 0)?;
    let hybrid: Wake = Hybrid::new(coarse.clone(), net0);
    let src_val = rollout(&hybrid, None, &validation, sizes.rollout)?.mean();
    validation_report.add("src", ds, None, src_val);
    let src_per_re = per_trajectory(&hybrid, None, &validation, sizes.rollout)?;
    for (re, e) in options.validation_re.iter().zip(&src_per_re) {
        validation_per_re
            .entry("src".into())
            .or_default()
            .entry(re.to_string())
            .or_default()
            .push(*e);
    }
    println!("  noise sigma (one-step RMS error of the coarse solver) {sigma:.2e}; src validation {src_val:.4} (per Re {src_per_re:.4?})");

    mem("src");
    Ok((train, validation, sigma))
}

/// Phases 2 and 3 of data seed `ds`: the learning rates on validation, then
/// every entry of the plan at every training seed; the groups at the main size
/// and those of the capacity sweep.
fn train_variants(
    ctx: &Ctx,
    ds: u64,
    (train, validation): (&[Trajectory], &[Trajectory]),
    sigma: f64,
    rec: &mut Record,
) -> Result<(Groups, Groups), BoxError> {
    let Ctx {
        options,
        seeds,
        args,
        coarse,
        ..
    } = ctx;
    let (threads, arithmetic, evaluations) = (ctx.threads, ctx.arithmetic, ctx.evaluations);
    let Record {
        validation_report,
        chosen_lr,
        train_seconds,
        validation_curves,
        validation_per_re,
        ..
    } = rec;
    let sizes = &ctx.sizes;
    // Phase 2: the learning rate, on validation (pilot runs at a quarter
    // of the budget, first training seed).
    let families: Vec<(&str, Variant)> = [
        ("non", Variant::Non),
        (
            "sol",
            Variant::Sol(options.unrolls().first().copied().unwrap_or(4)),
        ),
    ]
    .into_iter()
    .filter(|(f, _)| {
        if *f == "non" {
            options
                .variants
                .iter()
                .any(|v| matches!(v, Variant::Non | Variant::Noise))
        } else {
            !options.unrolls().is_empty()
        }
    })
    .collect();
    let setup = Setup {
        schedule: LrSchedule::Cosine {
            final_fraction: 0.1,
        },
        validation_steps: sizes.rollout,
        validation_evaluations: args.pick(VALIDATION_EVALUATIONS, 32),
        coarse,
        arithmetic,
        sigma,
        data_seed: ds,
        train,
        validation,
    };
    let run = |jobs: &[Job]| {
        run_jobs(jobs, threads, |job| {
            train_one(&setup, job).map_err(|e| e.to_string())
        })
    };
    let pilots = pilot_learning_rates(&families, &options.learning_rates, |pilots| {
        let first_seed = seeds.train[0];
        let jobs: Vec<Job> = pilots
            .iter()
            .map(|&((_, variant), lr)| Job {
                variant,
                size: MAIN_SIZE,
                seed: first_seed,
                lr,
                evaluations: evaluations.div_ceil(PILOT_DIVISOR),
            })
            .collect();
        Ok::<_, BoxError>(
            run(&jobs)?
                .iter()
                .map(|m| m.trained.model.validation)
                .collect(),
        )
    })?;
    let lr_of: BTreeMap<&str, f64> = pilots.chosen.iter().map(|&((f, _), lr)| (f, lr)).collect();
    for ((family, _), scores) in &pilots.scores {
        let best = lr_of[family];
        println!("  learning rate for {family}: {best:.0e} (pilot validation {scores:?})");
        chosen_lr.insert(
            format!("{family}_pilots_data_{ds}"),
            json!(scores
                .iter()
                .map(|(lr, v)| json!({"lr": lr, "validation": v}))
                .collect::<Vec<_>>()),
        );
    }
    for (f, lr) in &lr_of {
        chosen_lr.insert(format!("{f}_data_{ds}"), json!(lr));
    }
    let lr_for = |v: Variant| {
        match v {
            Variant::Sol(_) => lr_of.get("sol"),
            _ => lr_of.get("non"),
        }
        .copied()
        .unwrap_or(options.learning_rates[0])
    };

    // Phase 3: every variant at the main size and, for the capacity
    // sweep, non and the first SOL at the other sizes; every training seed.
    // The largest first, so the workers finish together.
    let sol = options.unrolls().first().copied().map(Variant::Sol);
    let mut plan: Vec<(Variant, NetSize)> = Vec::new();
    let mut sweep = options.capacity.clone();
    sweep.sort_by_key(|s| std::cmp::Reverse(s.width * s.width * (2 * s.blocks + 2)));
    let (larger, smaller): (Vec<NetSize>, Vec<NetSize>) = sweep
        .iter()
        .partition(|s| s.width * s.width * (2 * s.blocks + 2) > 16 * 16 * 6);
    for size in larger {
        for variant in [Some(Variant::Non), sol].into_iter().flatten() {
            plan.push((variant, size));
        }
    }
    for &variant in options.variants.iter().filter(|v| **v != Variant::Src) {
        plan.push((variant, MAIN_SIZE));
    }
    for size in smaller {
        for variant in [Some(Variant::Non), sol].into_iter().flatten() {
            plan.push((variant, size));
        }
    }
    let plan = Plan::new(plan, seeds.train.iter().map(|&s| TrainSeed(s)).collect());
    let jobs: Vec<Job> = plan
        .jobs()
        .into_iter()
        .map(|j| Job {
            variant: j.variant,
            size: j.size,
            seed: j.seed.0,
            lr: lr_for(j.variant),
            evaluations,
        })
        .collect();
    let mut groups: Vec<(Variant, Vec<Model>)> = Vec::new();
    let mut capacity_groups: Vec<(Variant, Vec<Model>)> = Vec::new();
    for Group {
        variant,
        size,
        runs: group,
        ..
    } in plan.groups(run(&jobs)?)?
    {
        for m in &group {
            let key = if size == MAIN_SIZE {
                validation_report.add(
                    &variant.name(),
                    ds,
                    Some(m.seed),
                    m.trained.model.validation,
                );
                for (re, e) in options.validation_re.iter().zip(&m.validation_per_re) {
                    validation_per_re
                        .entry(variant.name())
                        .or_default()
                        .entry(re.to_string())
                        .or_default()
                        .push(*e);
                }
                variant.name()
            } else {
                format!("{}_{}", variant.name(), size.label())
            };
            let t = &m.trained.model;
            validation_curves.insert(
                format!("{key}_data_{ds}_seed_{}", m.seed),
                json!({"curve": t.validation_curve, "kept_iteration": t.best_iteration,
                       "failures": t.validation_failures}),
            );
            train_seconds.entry(key).or_default().push(m.seconds);
        }
        if size == MAIN_SIZE {
            groups.push((variant, group));
        } else {
            capacity_groups.push((variant, group));
        }
    }

    mem("training");
    Ok((groups, capacity_groups))
}

/// Phases 4 and 5 of data seed `ds`: selection on validation, then the
/// held-out split, each trained model once (and saved); the selected SOL
/// corrector's parameters for the speed study.
fn select_and_evaluate(
    ctx: &Ctx,
    ds: u64,
    splits: &Splits<Vec<Reference>>,
    (groups, capacity_groups): (Groups, Groups),
    rec: &mut Record,
) -> Result<Option<Probe>, BoxError> {
    let Ctx {
        options,
        sizes,
        args,
        coarse,
        ..
    } = ctx;
    let (threads, arithmetic) = (ctx.threads, ctx.arithmetic);
    let Record {
        results,
        selected_k,
        selected_size,
        capacity_runs,
        held_out_readings,
        ..
    } = rec;
    let new_net = |size, seed| ctx.new_net(size, seed);
    // Phase 4: selection on validation only. Every SOL variant trained,
    // at every size, is a candidate: the unroll and the corrector's size
    // are both chosen here; the others are candidates on their own.
    let labelled = groups
        .into_iter()
        .chain(capacity_groups)
        .map(|(variant, g): (Variant, Vec<Model>)| {
            let size = g.first().map_or(MAIN_SIZE, |m| m.size);
            (Entry { variant, size }, g)
        })
        .collect();
    let selections = select_groups(
        labelled,
        |e| matches!(e.variant, Variant::Sol(_)),
        |m| m.trained.model.validation,
    )?;
    if let Some(Entry {
        variant: Variant::Sol(k),
        size,
    }) = selections.first().map(|s| *s.chosen_label())
    {
        let size = size.label();
        println!("  selected by validation: sol_{k} at {size}");
        selected_k.insert(ds.to_string(), json!(k));
        selected_size.insert(ds.to_string(), json!(size));
    }

    // Phase 5: held-out, each trained model once.
    let bar = progress_bar(
        options.held_out_re.len() * (1 + selections.iter().map(|s| s.models.len()).sum::<usize>()),
        &format!("data {ds}: held-out"),
    );
    let invalid = |e: BoxError| diffphys::learn::LearnError::Invalid {
        what: "held-out",
        message: e.to_string(),
    };
    // Each model at each held-out Re is one job; the workers share them.
    let evaluate = |models: &[(Option<&Params<f64>>, NetSize, u64)], refs: &[Reference]| {
        let jobs: Vec<(usize, usize)> = (0..models.len())
            .flat_map(|m| (0..refs.len()).map(move |r| (m, r)))
            .collect();
        let runs = run_jobs(&jobs, threads, |&(m, r)| {
            let (params, size, seed) = models[m];
            let (net, _) = new_net(size, seed).map_err(|e| e.to_string())?;
            let h = Hybrid::new(coarse.clone(), net);
            let run = study::held_out_re(&h, params, &refs[r], sizes).map_err(|e| e.to_string());
            bar.inc(1);
            run
        })?;
        let mut runs = runs.into_iter();
        Ok::<_, BoxError>(
            (0..models.len())
                .map(|_| HeldOutRun {
                    per_re: runs.by_ref().take(refs.len()).collect(),
                })
                .collect::<Vec<_>>(),
        )
    };
    let src = splits
        .held_out()
        .evaluate_baseline(|refs| evaluate(&[(None, MAIN_SIZE, 0)], refs).map_err(invalid))?
        .remove(0);
    results.record("src", ds, None, &src);
    let reference_last = splits
        .held_out()
        .evaluate_baseline(|refs| Ok(refs[0].states[sizes.long].clone()))?;
    results
        .last
        .entry("reference".into())
        .or_insert(reference_last);
    let mut probe: Option<(Params<f64>, NetSize)> = None;
    for selection in selections {
        for model in selection.models {
            let e = splits.held_out().evaluate(model, |group, refs| {
                let models: Vec<_> = group
                    .iter()
                    .map(|m| (Some(&m.trained.model.params), m.size, m.seed))
                    .collect();
                evaluate(&models, refs).map_err(invalid)
            })?;
            for (run, m) in e.result.iter().zip(&e.model) {
                let t = &m.trained.model;
                let card = model::card(sizes, m.size, arithmetic)
                    .provenance("variant", m.variant.name())
                    .provenance("chosen_on_validation", e.chosen)
                    .provenance("data_seed", ds)
                    .provenance("train_seed", m.seed)
                    .provenance("learning_rate", m.lr)
                    .provenance("corrector_evaluations", m.evaluations)
                    .provenance("kept_iteration", t.best_iteration)
                    .provenance("validation", t.validation)
                    .provenance("train_re", &options.train_re)
                    .provenance("validation_re", &options.validation_re)
                    .provenance("held_out_per_re", model::per_re_json(run));
                let name = model::dir_name(&m.variant.name(), m.size, ds, m.seed);
                SavedModel::save(args.out.join("models").join(name), &t.params, &card)?;
                let params = t.params.count();
                if m.size != MAIN_SIZE || matches!(m.variant, Variant::Non | Variant::Sol(_)) {
                    let first_sol = options.unrolls().first().copied();
                    let in_sweep =
                        m.variant == Variant::Non || Some(m.variant) == first_sol.map(Variant::Sol);
                    if in_sweep {
                        capacity_runs.push((
                            m.size,
                            m.variant,
                            m.seed,
                            run.mean(),
                            run.long_mean(),
                            params,
                        ));
                    }
                }
                if m.size == MAIN_SIZE {
                    results.record(&m.variant.name(), ds, Some(m.seed), run);
                }
                if matches!(m.variant, Variant::Sol(_)) && e.chosen {
                    results.record("sol_selected", ds, Some(m.seed), run);
                    if probe.is_none() {
                        probe = Some((m.trained.model.params.clone(), m.size));
                    }
                }
            }
        }
    }
    bar.finish_and_clear();
    mem("held-out");
    let (models_read, baseline_reads) = splits.held_out().readings();
    held_out_readings.insert(
        format!("data_{ds}"),
        json!({"trained_models": models_read, "baseline_readings": baseline_reads}),
    );
    Ok(probe)
}

/// Phase 6: speed against accuracy on the first data seed's held-out split
/// (a baseline reading), and the pressure solves inside a rollout.
fn speed_study(
    ctx: &Ctx,
    speed_inputs: Option<&(Splits<Vec<Reference>>, Option<Probe>)>,
    rec: &mut Record,
) -> Result<(Value, Value), BoxError> {
    let Ctx {
        options,
        sizes,
        coarse,
        ..
    } = ctx;
    let new_net = |size, seed| ctx.new_net(size, seed);
    let mut speed = Value::Null;
    let mut pressure = Value::Null;
    if let (true, Some((splits, probe))) = (options.speed, speed_inputs) {
        let size = probe.as_ref().map_or(MAIN_SIZE, |p| p.1);
        let (net0, _) = new_net(size, 0)?;
        let hybrid: Wake = Hybrid::new(coarse.clone(), net0);
        let params = probe.as_ref().map(|p| &p.0);
        let result = splits.held_out().evaluate_baseline(|refs| {
            study::speed(&hybrid, params, refs, sizes, &coarse.scene).map_err(|e| {
                diffphys::learn::LearnError::Invalid {
                    what: "speed",
                    message: e.to_string(),
                }
            })
        })?;
        speed = result;
        let (models_read, baseline_reads) = splits.held_out().readings();
        rec.held_out_readings.insert(
            format!("data_{}", splits.seed.0),
            json!({"trained_models": models_read, "baseline_readings": baseline_reads}),
        );
        mem("speed");
        pressure = study::pressure_solves(sizes, options.validation_re[0])?;
    }

    Ok((speed, pressure))
}

/// The tables, charts, `--npy` arrays and the JSON line.
fn report(
    ctx: &Ctx,
    rec: Record,
    (speed, pressure): (Value, Value),
    params_count: serde_json::Map<String, Value>,
    run_start: Instant,
) -> Result<(), BoxError> {
    let Ctx {
        options,
        sizes,
        seeds,
        args,
        coarse,
        fine,
        ..
    } = ctx;
    let (arithmetic, evaluations) = (ctx.arithmetic, ctx.evaluations);
    let Record {
        results,
        validation_report,
        selected_k,
        selected_size,
        chosen_lr,
        capacity_runs,
        train_seconds,
        validation_curves,
        validation_per_re,
        sigma_used,
        pinned_face_error,
        held_out_readings,
    } = rec;
    // Report.
    let summary = |r: &Report| -> serde_json::Map<String, Value> {
        r.methods()
            .filter_map(|m| {
                r.summary(m).map(|s| {
                    (
                        m.to_string(),
                        json!({"mean": s.mean, "min": s.min, "max": s.max, "runs": s.runs}),
                    )
                })
            })
            .collect()
    };
    println!(
        "\nheld-out mean relative L2 error over {} steps (data seeds {:?} x train seeds {:?}):",
        sizes.rollout, seeds.data, seeds.train
    );
    print!("{}", results.held_out.table(Some("src")));
    println!("long rollout ({} steps):", sizes.long);
    print!("{}", results.long.table(Some("src")));
    let per_re_json: serde_json::Map<String, Value> = results.per_re.iter()
        .map(|(re, m)| {
            let v: serde_json::Map<String, Value> = m
                .iter()
                .map(|(name, runs)| {
                    let n = runs.len() as f64;
                    let mean = runs.iter().map(|r| r.0).sum::<f64>() / n;
                    let long = runs.iter().map(|r| r.1).sum::<f64>() / n;
                    let min = runs.iter().map(|r| r.0).fold(f64::INFINITY, f64::min);
                    let max = runs.iter().map(|r| r.0).fold(f64::NEG_INFINITY, f64::max);
                    (name.clone(), json!({"mean": mean, "min": min, "max": max, "long_mean": long, "runs": runs.len()}))
                })
                .collect();
            (re.clone(), Value::Object(v))
        })
        .collect();
    // Floors.
    let ratio_at = |re: &str, a: &str, b: &str| -> Option<f64> {
        let m = results.per_re.get(re)?;
        let mean = |k: &str| {
            m.get(k)
                .map(|r| r.iter().map(|x| x.0).sum::<f64>() / r.len() as f64)
        };
        Some(mean(a)? / mean(b)?)
    };
    let sol_src: BTreeMap<String, Option<f64>> = results
        .per_re
        .keys()
        .map(|re| (re.clone(), ratio_at(re, "sol_selected", "src")))
        .collect();
    let floor_sol_src = if sol_src.values().any(Option::is_none) || sol_src.is_empty() {
        json!("not measured")
    } else {
        json!(sol_src.values().all(|r| r.unwrap_or(f64::INFINITY) <= 0.3))
    };
    let capacity = study::capacity_json(&capacity_runs, options);
    let smallest = study::ratio_at_size(
        &capacity_runs,
        SIZES[0],
        options.unrolls().first().copied(),
        false,
    );
    let smallest_long = study::ratio_at_size(
        &capacity_runs,
        SIZES[0],
        options.unrolls().first().copied(),
        true,
    );
    let floor_small = match smallest {
        Some(r) => json!(r <= 0.8),
        None => json!("not measured"),
    };
    study::validation_chart(&args.out, &validation_curves)?;
    study::charts(
        &args.out,
        &results.curves,
        &capacity_runs,
        &speed,
        &results.last,
        &coarse.scene,
        options.unrolls().first().copied(),
    )?;
    let npy: Vec<(String, ndarray::ArrayViewD<'_, f64>)> = results
        .last
        .iter()
        .map(|(name, a)| (format!("last_{name}"), a.view().into_dyn()))
        .collect();
    args.write_npy(
        &npy.iter()
            .map(|(n, a)| {
                (
                    n.as_str(),
                    a.view(),
                    "packed [2, nx + 1, ny + 1] velocity (u_x, u_y; viscosity in the corner) after the long rollout at the first held-out Re",
                )
            })
            .collect::<Vec<_>>(),
    )?;
    let floors = json!({
        "sol_selected_at_most_0.3x_src_every_held_out_re": floor_sol_src,
        "sol_selected_over_src_per_re": sol_src,
        "goal_sol_selected_at_most_0.1x_src": if sol_src.is_empty() || sol_src.values().any(Option::is_none) { json!("not measured") } else { json!(sol_src.values().all(|r| r.unwrap_or(f64::INFINITY) <= 0.1)) },
        "smallest_size_sol_at_most_0.8x_non_100_steps": floor_small,
        "smallest_size_sol_over_non_100_steps": smallest,
        "smallest_size_sol_over_non_long": smallest_long,
        "peak_rss_under_2_gib": common::peak_rss_bytes().map(|b| b < 2 << 30),
    });
    println!("floors: {floors}");
    let training_iterations: serde_json::Map<String, Value> = options
        .variants
        .iter()
        .filter(|v| **v != Variant::Src)
        .map(|&v| (v.name(), json!(v.adam_steps(evaluations))))
        .collect();
    let held_split: (Vec<f64>, Vec<f64>) = options
        .held_out_re
        .iter()
        .partition(|&&r| options.inside(r));
    // How the body and the reference were made, and the error they leave on
    // the pinned faces (a key of its own: the line's macro is deep already).
    let setup_json = json!({
        "body": sizes.body.label(),
        "reference_scheme": sizes.reference.label(),
        "coarse_advection": wake_flow_scene::advection_label(sizes.advection),
        "network_arithmetic": wake_flow_scene::arithmetic_label(arithmetic),
        "pinned_face_error": pinned_face_error,
    });
    let mut line = json!({
        "example": "wake_flow",
        "small": args.small,
        "grid_coarse": [sizes.ny, sizes.nx],
        "grid_reference": [fine.grid().ny, fine.grid().nx],
        "dt_coarse": sizes.dt,
        "dt_reference": fine.dt(),
        "skipped_transient_steps": {"base": sizes.warm_base, "per_re": sizes.warm, "base_re": sizes.base_re},
        "recorded_steps": sizes.record,
        "rollout_steps": sizes.rollout,
        "rollout_starts": sizes.starts,
        "long_rollout_steps": sizes.long,
        "re_definition": "U D / nu, U = 1 inflow speed, D = 0.2 cylinder diameter",
        "re_range": wake_flow_scene::RE_RANGE,
        "data_seeds": seeds.data,
        "train_seeds": seeds.train,
        "train_re": options.train_re,
        "validation_re": options.validation_re,
        "held_out_re": {"inside": held_split.0, "outside": held_split.1},
        "training_iterations": training_iterations,
        "corrector_evaluations_per_training": evaluations,
        "noise_sigma": sigma_used,
        "setup": setup_json,
        "learning_rate": chosen_lr,
        "params": params_count,
        "main_size": MAIN_SIZE.label(),
        "mean_rel_error": summary(&results.held_out),
        "long_rel_error": summary(&results.long),
        "validation_rel_error": summary(&validation_report),
        "per_re": per_re_json,
        "capacity": capacity,
        "selected_k": selected_k,
        "selected_size": selected_size,
        "selected_by": "validation",
        "train_seconds": train_seconds,
        "validation_curves": validation_curves,
        "validation_per_re": validation_per_re
            .iter()
            .map(|(v, per)| {
                let stats: serde_json::Map<String, Value> = per
                    .iter()
                    .map(|(re, e)| (re.clone(), study::stats(e)))
                    .collect();
                (v.clone(), Value::Object(stats))
            })
            .collect::<serde_json::Map<String, Value>>(),
        "speed": speed,
        "pressure": pressure,
        "floors_met": floors,
        "peak_rss_bytes": common::peak_rss_bytes(),
        "wall_s": run_start.elapsed().as_secs_f64(),
    });
    // Beside the macro: its recursion is deep already.
    line["held_out_readings"] = held_out_readings.into();
    line["saved_models"] = json!(args.out.join("models").display().to_string());
    common::print_json_line(&line);
    Ok(())
}

/// Per Reynolds number, per method: `(100-step error, long error)` of every run.
type PerRe = BTreeMap<String, BTreeMap<String, Vec<(f64, f64)>>>;

/// The held-out figures of every run.
#[derive(Default)]
struct Results {
    held_out: Report,
    long: Report,
    per_re: PerRe,
    curves: BTreeMap<String, Vec<Vec<f64>>>,
    last: BTreeMap<String, Array3<f64>>,
}

impl Results {
    fn record(&mut self, name: &str, ds: u64, ts: Option<u64>, run: &HeldOutRun) {
        self.held_out.add(name, ds, ts, run.mean());
        self.long.add(name, ds, ts, run.long_mean());
        for r in &run.per_re {
            self.per_re
                .entry(format!("{}", r.re))
                .or_default()
                .entry(name.to_string())
                .or_default()
                .push((r.mean, r.long));
        }
        self.curves
            .entry(name.to_string())
            .or_default()
            .push(run.curve());
        if let Some(r) = run.per_re.first() {
            self.last
                .entry(name.to_string())
                .or_insert_with(|| r.last.clone());
        }
    }
}

/// Prints the peak resident memory so far (the tapes' buffer pools are freed
/// with the training runs that made them).
fn mem(phase: &str) {
    println!(
        "  memory after {phase}: peak RSS {:.0} MB",
        common::peak_rss_bytes().unwrap_or(0) as f64 / 1e6
    );
}
