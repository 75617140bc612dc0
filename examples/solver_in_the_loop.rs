//! Solver in the loop: a network corrects a coarse advection solver after every
//! step, trained on one-step pairs (`non`), the same with noisy inputs (`noise`),
//! and through `k` unrolled steps of solver and network (`sol_k`, k = 2, 4, 8,
//! 16), each with the same budget; then checkpointing of a 1024-step unroll.
//!
//! Scene (physics in `solver_in_the_loop_scene`): 1D periodic advection of
//! square pulses by `1 + ½ sin πx`, upwind on 32 cells against 256 cells with
//! eight substeps, averaged to 32. Network: a periodic 1D U-Net (widths 16, 32,
//! kernel 5, ReLU) that sees the state and the velocity; its head starts at zero.
//! Budget: 2000 Adam steps (3e-3 decayed to 3e-4) of 64 network evaluations.
//!
//! Protocol (`diffphys-learn`): every `--data-seed` draws train (48), validation
//! (16) and held-out (16) trajectories of 128 steps from separate streams; every
//! `--train-seeds` entry trains every variant once. Early stopping and the choice
//! of `k` read validation only; each trained model is evaluated once on the
//! held-out split, after selection. Default: data seeds 1, 2, 3 × training seeds
//! 1, 2, 3. Tutorial: docs/07-solver-in-the-loop.md. Run:
//! `cargo run --release --example solver_in_the_loop` (`-- --small` for CI).

mod common;
mod solver_in_the_loop_scene;

use solver_in_the_loop_scene::study;

use std::collections::BTreeMap;
use std::time::Instant;

use diffphys::learn::study::{Job, OneSize, Plan, Protocol, TrainJob, Trainings, Variant};
use diffphys::learn::{
    missed_floors, rollout, states_at, DataSeed, Hybrid, LrSchedule, Report, Split, Splits,
    TrainSeed,
};
use diffphys::nn::Params;
use diffphys::prelude::{check_gradient, GradCheckOptions};
use diffphys_compare::alloc::CountingAllocator;
use serde_json::json;

use solver_in_the_loop_scene::{network, one_step_rms, trajectories, BoxError, Solver};

/// Counts heap bytes for the checkpointing measurements.
#[global_allocator]
static HEAP: CountingAllocator = CountingAllocator::new();

const UNROLLS: [usize; 4] = [2, 4, 8, 16];
const LEARNING_RATE: f64 = 3e-3;
/// `noise`'s σ as a fraction of one coarse step's RMS error on the training split.
const NOISE_FRACTION: f64 = 0.1;
/// The checkpoint schedule of the JSON tail: every √1024 steps.
const HEADLINE_SEGMENT: usize = 32;

/// Solver-in-the-loop: a corrector trained through the solver it corrects.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    #[command(flatten)]
    seeds: common::Seeds,
    /// Adam steps (8 with --small).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 2000,
        default_value_if("small", "true", "8")
    )]
    iterations: usize,
}

fn main() -> Result<(), BoxError> {
    let run_start = Instant::now();
    let Cli {
        common: args,
        seeds,
        iterations,
    } = common::parse_args("solver_in_the_loop")?;
    let [train_n, validation_n, held_out_n] = args.pick([48, 16, 16], [4, 2, 2]);
    let steps = args.pick(128, 32);
    // Every variant: 64 network evaluations per Adam step (one window holds
    // k of them, so sol_k draws 64 / k windows).
    let evaluations_per_step = 64;
    let solver = Solver::coarse()?;
    let (net, untrained) = network(TrainSeed(0))?;
    let hybrid = Hybrid::new(solver.clone(), net);

    let (mut held_out, mut validation) = (Report::new(), Report::new());
    let mut curves: BTreeMap<String, Vec<Vec<f64>>> = BTreeMap::new();
    let mut selected_k = serde_json::Map::new();
    let mut probe_model: Option<(u64, Params<f64>)> = None;
    for &ds in &seeds.data {
        let splits = Splits::generate(
            DataSeed(ds),
            [train_n, validation_n, held_out_n],
            |_, n, rng| {
                trajectories(n, steps, rng).map_err(|e| diffphys::learn::LearnError::Invalid {
                    what: "reference",
                    message: e.to_string(),
                })
            },
        )?;
        if ds == seeds.data[0] {
            // The coarse step's hand-written adjoint against central differences.
            let check = check_gradient(
                |_, v| solver.step_tape(v[0]),
                &[states_at(&splits.train[..2], 8)?.fields.remove(0)],
                GradCheckOptions::for_type::<f64>(),
            )?;
            println!(
                "coarse step gradient check: {} entries, max relative error {:.1e}",
                check.entries, check.max_rel_err
            );
            if !check.passed {
                return Err(format!(
                    "the coarse step's adjoint fails its gradient check: {check:?}"
                )
                .into());
            }
        }
        let sigma = NOISE_FRACTION * one_step_rms(&solver, &splits.train)?;
        println!("data seed {ds}: {train_n}/{validation_n}/{held_out_n} trajectories of {steps} steps; {} parameters; noise σ = {sigma:.4}", untrained.count());
        let mut variants = vec![Variant::Non, Variant::Noise];
        variants.extend(UNROLLS.map(Variant::Sol));
        // Train every variant at every seed, select k on validation only,
        // then read the held-out split once per trained model.
        let plan = Plan::new(
            variants.into_iter().map(|v| (v, OneSize)).collect(),
            seeds.train.iter().map(|&ts| TrainSeed(ts)).collect(),
        );
        let corrector = |_: OneSize, ts: TrainSeed| network(ts);
        let trainings = Trainings {
            simulator: &solver,
            corrector: &corrector,
            schedule: LrSchedule::Exponential {
                final_fraction: 0.1,
            },
            step_evaluations: evaluations_per_step,
            checkpoint: None,
            validation_steps: steps,
            validation_evaluations: args.pick(100, 4) * evaluations_per_step,
            sigma,
            train: &splits.train,
            validation: &splits.validation,
            label: format!("data {ds}"),
        };
        // A hybrid of its own per training: they may run on other threads.
        let train = |job: &Job<Variant, OneSize>| {
            trainings.train(&TrainJob {
                variant: job.variant,
                size: OneSize,
                seed: job.seed,
                lr: LEARNING_RATE,
                evaluations: iterations * evaluations_per_step,
            })
        };
        let coarse = splits
            .held_out()
            .evaluate_baseline(|d| rollout(&hybrid, None, d, steps))?;
        let outcomes = Protocol {
            plan: &plan,
            threads: 1,
        }
        .run(
            splits.held_out(),
            train,
            |t| t.trained.model.validation,
            |e| e.variant.is_sol(),
            |_, models, d| {
                Ok(models
                    .iter()
                    .map(|t| rollout(&hybrid, Some(&t.trained.model.params), d, steps))
                    .collect::<Result<Vec<_>, _>>()?)
            },
        )?;
        held_out.add("coarse", ds, None, coarse.mean());
        curves
            .entry("coarse".into())
            .or_default()
            .push(coarse.per_step);
        if let Some(o) = outcomes.iter().find(|o| o.selected()) {
            println!("  selected by validation: {}", o.entry.variant);
            selected_k.insert(ds.to_string(), json!(o.entry.variant.unroll()));
            probe_model.get_or_insert((ds, o.runs[0].model.trained.model.params.clone()));
        }
        for o in &outcomes {
            let name = o.entry.variant.name();
            let names = [Some(name.as_str()), o.selected().then_some("sol_selected")];
            for run in &o.runs {
                validation.add(
                    &name,
                    ds,
                    Some(run.seed.0),
                    run.model.trained.model.validation,
                );
                for name in names.iter().flatten() {
                    held_out.add(name, ds, Some(run.seed.0), run.held_out.mean());
                    let curve = run.held_out.per_step.clone();
                    curves.entry(name.to_string()).or_default().push(curve);
                }
            }
        }
    }
    println!(
        "\nheld-out mean relative error over {steps} steps (data seeds {:?} × train seeds {:?}):",
        seeds.data, seeds.train
    );
    print!("{}", held_out.table(Some("non")));
    let mean = |m: &str| held_out.summary(m).map_or(f64::NAN, |s| s.mean);
    let ratio = mean("sol_selected") / mean("non");
    let per_seed: Vec<(u64, f64)> = held_out
        .per_data_seed("sol_selected")
        .iter()
        .zip(held_out.per_data_seed("non"))
        .map(|(&(ds, sol), (_, non))| (ds, sol / non))
        .collect();
    println!("sol at the validation-selected k: {ratio:.3} × non; per data seed {per_seed:?}; noise {:.3} × non", mean("noise") / mean("non"));

    // Checkpointing a long unroll of the selected corrector.
    let (ds, params) = probe_model.ok_or("no selected model")?;
    let long = args.pick(1024, 64);
    let probe = trajectories(2, long, &mut DataSeed(ds).rng(Split::Validation))?;
    let runs = study::checkpointing(&hybrid, &params, &probe, &|| HEAP.reset_peak(), &|| {
        (HEAP.current(), HEAP.peak())
    })?;
    let (worst, heap_ratio, time_ratio) = study::summary(&runs, HEADLINE_SEGMENT)?;
    study::charts(&args.out, &curves, &runs)?;
    let below_everywhere = per_seed.iter().all(|&(_, r)| r < 1.0);
    let floors = json!({
        "sol_selected_at_most_0.75x_non": ratio <= 0.75,
        "sol_selected_below_non_every_data_seed": below_everywhere,
        "goal_sol_selected_at_most_0.5x_non_every_data_seed": per_seed.iter().all(|&(_, r)| r <= 0.5),
        "checkpoint_gradients_within_1e-12": worst <= 1e-12,
    });
    println!("floors: {floors}");
    common::print_json_line(&json!({
        "example": "solver_in_the_loop",
        "small": args.small,
        "data_seeds": seeds.data,
        "train_seeds": seeds.train,
        "rollout_steps": steps,
        "training_iterations": iterations,
        "network_evaluations_per_training": iterations * evaluations_per_step,
        "held_out_mean_rel_error": held_out.to_json(),
        "validation_mean_rel_error": validation.to_json(),
        "selected_k": selected_k,
        "selected_by": "validation",
        "sol_selected_over_non": ratio,
        "sol_selected_over_non_per_data_seed": per_seed.iter().map(|(d, r)| (d.to_string(), json!(r))).collect::<serde_json::Map<_, _>>(),
        "noise_over_non": mean("noise") / mean("non"),
        "checkpoint_steps": long,
        "checkpoint_schedule": format!("every {HEADLINE_SEGMENT}"),
        "checkpoint_peak_heap_ratio": heap_ratio,
        "checkpoint_time_ratio": time_ratio,
        "checkpoint_grad_max_abs_diff": worst,
        "floors_met": floors,
        "peak_rss_bytes": common::peak_rss_bytes(),
        "seconds": run_start.elapsed().as_secs_f64(),
    }));
    // The floors are the full scene's; the checkpoint's gradients must agree
    // at any size.
    let missed = missed_floors(&floors);
    if missed
        .iter()
        .any(|f| !args.small || f.starts_with("checkpoint"))
    {
        return Err(format!("a floor of the scene is not met: {}", missed.join(", ")).into());
    }
    Ok(())
}
