//! A network produces the solver's input (network → solver): from the observed
//! state of the Burgers scene of `burgers_inverse` (the state after step 16), a
//! 1D U-Net predicts the initial state.
//!
//! The same network, from the same initial parameters, on the same batches, is
//! trained two ways: through the solver (differentiable physics), with the loss
//! `mean((P(net(obs)) − obs)²)` where `P` is the 16 recorded solver steps, and
//! supervised, with `mean((net(obs) − u₀)²)` on the known initial states. Each
//! keeps the parameters that score best on the validation split by its own
//! objective (early stopping); the held-out split is read once per trained
//! network, after training, where both are compared with a zero initial state,
//! with per-instance optimisation (the 50 gradient-descent steps of
//! `burgers_inverse` on each case) and with the network's prediction refined by
//! 5 of those steps. Every figure is over data seeds × training seeds.
//!
//! Tutorial: docs/06-training-through-the-solver.md. Run:
//! `cargo run --release --example nn_control_burgers` (`-- --small` for CI).

mod burgers_scene;
mod common;
mod nn_control_burgers_scene;

use std::time::Instant;

use burgers_scene::{batch_of, network, BoxError, Burgers, DESCENT_RATE, N};
use diffphys::learn::fit::{Fit, Validation};
use diffphys::learn::study::run_jobs;
use diffphys::learn::{
    select_best, Candidate, DataSeed, LearnError, LrSchedule, Report, Splits, TrainSeed, Trained,
};
use diffphys::nn::Layer;
use diffphys::prelude::*;
use diffphys::report::progress_bar;
use ndarray::Array1;
use nn_control_burgers_scene::{
    baselines, descent_json, held_out_network, network_predictions, score, write_charts, Baselines,
    Cases, HeldOutNetwork, Run, Training, REFINE_STEPS,
};
use rand::Rng;
use serde_json::{json, Value};

/// Adam's initial step size, the same for both trainings (cosine decay to 1/20).
const ADAM_RATE: f64 = 2e-3;

/// The training budget, the same for both trainings.
#[derive(Debug, Clone, Copy)]
struct Budget {
    steps: usize,
    batch: usize,
    eval_every: usize,
}

/// A scene error where the fit loop expects its own.
fn learn_error(what: &'static str) -> impl Fn(BoxError) -> LearnError {
    move |e| LearnError::Invalid {
        what,
        message: e.to_string(),
    }
}

/// Trains `training` from training seed `seed` (initial parameters and batch
/// order) on the training cases, validating on the validation cases every
/// `eval_every` steps.
fn train(
    scene: &Burgers,
    training: Training,
    (data, validation): (&Cases, &Cases),
    data_seed: u64,
    budget: Budget,
    seed: TrainSeed,
) -> Result<Run, BoxError> {
    let (params, net) = network(seed.0)?;
    let mut batches = seed.sampling_rng();
    let fit = Fit {
        steps: budget.steps,
        learning_rate: ADAM_RATE,
        schedule: LrSchedule::Cosine {
            final_fraction: 0.05,
        },
        validate_every: budget.eval_every,
        validation: Validation::FromUntrained,
    };
    let (mut physics, mut u0_error) = (Vec::new(), Vec::new());
    let bar = progress_bar(
        budget.steps,
        &format!("data {} {} seed {}", data_seed, training.key(), seed.0),
    );
    let fitted = fit.run(
        "nn_control_burgers",
        params,
        |_, tape, p| {
            let picks: Vec<usize> = (0..budget.batch)
                .map(|_| batches.random_range(0..data.len()))
                .collect();
            let obs = tape.constant(batch_of(
                &picks.iter().map(|&i| &data.obs[i]).collect::<Vec<_>>(),
            ));
            let pred = net.forward(p, obs)?;
            let residual = match training {
                Training::Physics => scene
                    .observe_batch(pred)
                    .map_err(learn_error("the solver"))?
                    .sub(obs)?,
                Training::Supervised => {
                    let u0 = batch_of(&picks.iter().map(|&i| &data.u0[i]).collect::<Vec<_>>());
                    pred.sub(tape.constant(u0))?
                }
            };
            Ok(residual.powi(2)?.mean()?)
        },
        |params| {
            let run = || -> Result<(f64, f64), BoxError> {
                score(
                    scene,
                    validation,
                    &network_predictions(&net, params, validation)?,
                )
            };
            let (p, u) = run().map_err(learn_error("validation"))?;
            physics.push(p);
            u0_error.push(u);
            Ok(match training {
                Training::Physics => p,
                Training::Supervised => u,
            })
        },
        &|| bar.inc(1),
    )?;
    bar.finish_and_clear();
    let steps: Vec<usize> = fitted.curve.iter().map(|c| c.0).collect();
    let along = |v: Vec<f64>| steps.iter().copied().zip(v).collect();
    Ok(Run {
        training,
        data_seed,
        train_seed: seed.0,
        net,
        validation: fitted.validation,
        kept_step: fitted.best_step,
        validation_physics: along(physics),
        validation_u0_error: along(u0_error),
        final_training_loss: fitted.losses.last().copied().unwrap_or(f64::NAN),
        seconds: fitted.seconds,
        params: fitted.params,
    })
}

/// The held-out figures of every run, and the details of the first.
#[derive(Default)]
struct HeldOutFigures {
    physics: Report,
    u0_error: Report,
    seconds: Report,
    /// Data seed → `(trained networks, baseline readings)` of its split.
    readings: serde_json::Map<String, Value>,
}

/// What the held-out split gave, with the runs it came from.
struct Outcome {
    figures: HeldOutFigures,
    validation: Report,
    runs: Vec<Run>,
    /// The first data seed's baselines, and its first training seed's
    /// networks.
    baselines: Baselines,
    networks: Vec<(Training, HeldOutNetwork)>,
}

/// A network predicts the Burgers scene's initial state, trained through the solver and supervised.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    #[command(flatten)]
    seeds: common::Seeds,
    /// Adam steps (20 with --small).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 3000,
        default_value_if("small", "true", "20")
    )]
    iterations: usize,
}

fn main() -> Result<(), BoxError> {
    let run_start = Instant::now();
    let Cli {
        common: args,
        seeds,
        iterations,
    } = common::parse_args("nn_control_burgers")?;
    let budget = Budget {
        steps: iterations,
        batch: args.pick(16, 4),
        eval_every: args.pick(50, 10),
    };
    let sizes = args.pick([1024, 64, 64], [32, 8, 8]);
    let scene = Burgers::new()?;
    let splits: Vec<Splits<Cases>> = seeds
        .data
        .iter()
        .map(|&ds| {
            Splits::generate(DataSeed(ds), sizes, |_, n, rng| {
                Cases::draw(&scene, n, rng).map_err(learn_error("cases"))
            })
        })
        .collect::<Result<_, _>>()?;
    println!(
        "Burgers, {N} cells, observed after 16 steps; {} training, {} validation, {} held-out \
         cases per data seed {:?}; training seeds {:?}",
        sizes[0], sizes[1], sizes[2], seeds.data, seeds.train
    );
    let runs = train_all(&scene, &splits, &seeds.train, budget)?;
    let outcome = held_out(&scene, &splits, &seeds, runs)?;
    report(&args, &scene, budget, &seeds, sizes, &outcome, run_start)
}

/// Every (data seed, training seed, training), on the machine's cores; each
/// is deterministic for its seeds, so the order of the results is the jobs'.
fn train_all(
    scene: &Burgers,
    splits: &[Splits<Cases>],
    train_seeds: &[u64],
    budget: Budget,
) -> Result<Vec<Run>, BoxError> {
    let parts: Vec<(&Cases, &Cases, u64)> = splits
        .iter()
        .map(|s| (&s.train, &s.validation, s.seed.0))
        .collect();
    let mut jobs = Vec::new();
    for d in 0..parts.len() {
        for &ts in train_seeds {
            for training in [Training::Physics, Training::Supervised] {
                jobs.push((d, ts, training));
            }
        }
    }
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let runs = run_jobs(&jobs, threads, |&(d, ts, training)| {
        let (data, validation, ds) = parts[d];
        train(
            scene,
            training,
            (data, validation),
            ds,
            budget,
            TrainSeed(ts),
        )
        .map_err(|e| e.to_string())
    })?;
    for r in &runs {
        println!(
            "{:>22}, data {} seed {}: {} steps of batch {} in {:.1} s ({:.1} ms per step), final \
             training loss {:.3e}, validation {:.3e} (kept step {})",
            r.training.label(),
            r.data_seed,
            r.train_seed,
            budget.steps,
            budget.batch,
            r.seconds,
            1e3 * r.seconds / budget.steps.max(1) as f64,
            r.final_training_loss,
            r.validation,
            r.kept_step,
        );
    }
    Ok(runs)
}

/// The held-out split of each data seed: its baselines, then each trained
/// network once.
fn held_out(
    scene: &Burgers,
    splits: &[Splits<Cases>],
    seeds: &common::Seeds,
    runs: Vec<Run>,
) -> Result<Outcome, BoxError> {
    let mut figures = HeldOutFigures::default();
    let mut validation = Report::new();
    let mut first: Option<Baselines> = None;
    let mut networks: Vec<(Training, HeldOutNetwork)> = Vec::new();
    let mut kept = Vec::new();
    let mut runs = runs.into_iter();
    for s in splits {
        let ds = s.seed.0;
        let b = s
            .held_out()
            .evaluate_baseline(|cases| baselines(scene, cases).map_err(learn_error("held-out")))?;
        for (method, (physics, u0_error)) in [("zero", b.zero), ("per_instance", b.per_instance)] {
            figures.physics.add(method, ds, None, physics);
            figures.u0_error.add(method, ds, None, u0_error);
        }
        figures
            .seconds
            .add("per_instance", ds, None, b.seconds_per_instance);
        first.get_or_insert(b);
        for run in runs.by_ref().take(2 * seeds.train.len()) {
            // Nothing to choose between: each trained network is its own
            // candidate, scored on validation by its own objective.
            let (training, ts, score) = (run.training, run.train_seed, run.validation);
            validation.add(training.key(), ds, Some(ts), score);
            let selection = select_best(vec![Candidate::new(training, Trained::new(run), score)])?;
            for model in selection.models {
                let e = s.held_out().evaluate(model, |run, cases| {
                    held_out_network(scene, run, cases).map_err(learn_error("held-out"))
                })?;
                let (key, h) = (training.key(), &e.result);
                let refined = format!("{key}_refined");
                for (method, physics, u0_error, seconds) in [
                    (key, h.physics, h.u0_error, h.seconds_network),
                    (
                        &refined,
                        h.refined_physics,
                        h.refined_u0_error,
                        h.seconds_refined,
                    ),
                ] {
                    figures.physics.add(method, ds, Some(ts), physics);
                    figures.u0_error.add(method, ds, Some(ts), u0_error);
                    figures.seconds.add(method, ds, Some(ts), seconds);
                }
                if ds == seeds.data[0] && ts == seeds.train[0] {
                    networks.push((training, e.result));
                }
                kept.push(e.model);
            }
        }
        let (models, baseline_reads) = s.held_out().readings();
        figures.readings.insert(
            ds.to_string(),
            json!({"trained_models": models, "baseline_readings": baseline_reads}),
        );
    }
    Ok(Outcome {
        figures,
        validation,
        runs: kept,
        baselines: first.ok_or("no data seed")?,
        networks,
    })
}

/// Tables, descent traces, charts, `--npy` arrays and the JSON line.
fn report(
    args: &common::ExampleArgs,
    scene: &Burgers,
    budget: Budget,
    seeds: &common::Seeds,
    sizes: [usize; 3],
    o: &Outcome,
    run_start: Instant,
) -> Result<(), BoxError> {
    let f = &o.figures;
    let runs = format!(
        "data seeds {:?} x training seeds {:?}",
        seeds.data, seeds.train
    );
    println!("held-out physics loss ({runs}):");
    print!("{}", f.physics.table(Some("zero")));
    println!("held-out initial-state error:");
    print!("{}", f.u0_error.table(Some("zero")));
    println!("seconds per held-out case:");
    print!("{}", f.seconds.table(None));
    let network = |t: Training| {
        o.networks
            .iter()
            .find(|n| n.0 == t)
            .map(|n| &n.1)
            .ok_or_else(|| format!("no held-out figures of the {t} network"))
    };
    let (dp, supervised) = (network(Training::Physics)?, network(Training::Supervised)?);
    let b = &o.baselines;
    println!(
        "gradient descent (rate {DESCENT_RATE}) from each start, data seed {} training seed {}: \
         mean held-out physics loss before steps 1..{REFINE_STEPS} and after",
        seeds.data[0], seeds.train[0]
    );
    let mut descents = serde_json::Map::new();
    for (label, d) in [
        ("zero", &b.descent),
        ("dp", &dp.descent),
        ("supervised", &supervised.descent),
    ] {
        let losses: Vec<String> = d.losses.iter().map(|l| format!("{l:.3e}")).collect();
        println!(
            "{label:>11}: {}; best iterate {:.3e}; |gradient| {:.3e}; loss higher after \
             {REFINE_STEPS} steps in {} of {} cases",
            losses.join(" "),
            d.best,
            d.gradient_norm,
            d.cases_worse,
            b.truth.len()
        );
        descents.insert(label.to_string(), descent_json(d));
    }
    let shown = [
        ("true u0", &b.truth[0]),
        ("DP network", &dp.predictions[0]),
        ("supervised network", &supervised.predictions[0]),
        ("per-instance (50 GD)", &b.per_instance_u0[0]),
    ];
    let first: Vec<&Run> = o
        .runs
        .iter()
        .filter(|r| r.data_seed == seeds.data[0])
        .collect();
    let levels = [
        ("zero initial state (held-out)", b.zero.0),
        ("per-instance, 50 GD steps (held-out)", b.per_instance.0),
    ];
    for file in write_charts(&args.out, scene, &first, budget.steps, &levels, shown)? {
        println!("wrote {}", file.display());
    }
    let stacked = |rows: &[Array1<f64>]| -> Result<ArrayD<f64>, BoxError> {
        let views: Vec<_> = rows.iter().map(|r| r.view()).collect();
        Ok(ndarray::stack(ndarray::Axis(0), &views)?.into_dyn())
    };
    let npy = [
        (
            "heldout_u0",
            stacked(&b.truth)?,
            "held-out true initial states [cases, 128]",
        ),
        (
            "heldout_observed",
            stacked(&b.observed)?,
            "held-out observed states at step 16 [cases, 128]",
        ),
        (
            "u0_network_dp",
            stacked(&dp.predictions)?,
            "initial states from the network trained through the solver",
        ),
        (
            "u0_network_supervised",
            stacked(&supervised.predictions)?,
            "initial states from the supervised network",
        ),
        (
            "u0_per_instance",
            stacked(&b.per_instance_u0)?,
            "initial states after 50 gradient steps from zero",
        ),
        (
            "u0_warm_started",
            stacked(&dp.refined)?,
            "the solver-trained network's states refined by 5 gradient steps",
        ),
    ];
    args.write_npy(
        &npy.iter()
            .map(|(n, a, m)| (*n, a.view(), *m))
            .collect::<Vec<_>>(),
    )?;
    let mean = |r: &Report, m: &str| r.summary(m).map(|s| s.mean);
    let seconds_of = |t: Training| {
        o.runs
            .iter()
            .filter(|r| r.training == t)
            .map(|r| r.seconds)
            .sum::<f64>()
    };
    let mut line = json!({
        "example": "nn_control_burgers",
        "small": args.small,
        "data_seeds": seeds.data,
        "train_seeds": seeds.train,
        "training_cases": sizes[0],
        "validation_cases": sizes[1],
        "heldout_cases": sizes[2],
        "training_steps": budget.steps,
        "batch": budget.batch,
        "parameters": o.runs.first().map(|r| r.params.count()),
        "selected_by": "validation (each training's own objective; early stopping)",
        "heldout_physics_loss_dp": mean(&f.physics, "dp"),
        "heldout_physics_loss_supervised": mean(&f.physics, "supervised"),
        "heldout_physics_loss_zero": mean(&f.physics, "zero"),
        "heldout_physics_loss_per_instance": mean(&f.physics, "per_instance"),
        "heldout_physics_loss_warm_started": mean(&f.physics, "dp_refined"),
        "heldout_physics_loss_warm_started_supervised": mean(&f.physics, "supervised_refined"),
        "heldout_u0_error_dp": mean(&f.u0_error, "dp"),
        "heldout_u0_error_supervised": mean(&f.u0_error, "supervised"),
        "heldout_u0_error_zero": mean(&f.u0_error, "zero"),
        "heldout_u0_error_per_instance": mean(&f.u0_error, "per_instance"),
        "heldout_u0_error_warm_started": mean(&f.u0_error, "dp_refined"),
        "training_seconds_dp": seconds_of(Training::Physics),
        "training_seconds_supervised": seconds_of(Training::Supervised),
        "seconds_per_case_network": mean(&f.seconds, "dp"),
        "seconds_per_case_per_instance": mean(&f.seconds, "per_instance"),
        "seconds_per_case_warm_started": mean(&f.seconds, "dp_refined"),
    });
    line["heldout_physics_loss"] = f.physics.to_json();
    line["heldout_u0_error"] = f.u0_error.to_json();
    line["validation"] = o.validation.to_json();
    line["held_out_readings"] = Value::Object(f.readings.clone());
    line["refinement"] = Value::Object(descents);
    line["wall_s"] = json!(run_start.elapsed().as_secs_f64());
    common::print_json_line(&line);
    Ok(())
}
