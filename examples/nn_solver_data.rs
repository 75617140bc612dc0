//! The solver as a data generator (solver → network): a 1D U-Net learns the map
//! from the initial state of the Burgers scene of `burgers_inverse` to its state
//! after step 16, from pairs the solver produces.
//!
//! Physics: `burgers_scene` (128 cells, periodic, viscous Burgers). Network: its
//! U-Net (widths 16, 32, 32, 32, kernel 5, ReLU). Budget: 1500 Adam steps of 16
//! pairs (2e-3, cosine to 1/20), the same for every source: (a) pairs drawn and
//! solved afresh at every step from the training stream, (b) fixed sets of the
//! first 64, 256 and 1024 pairs of that stream, computed once.
//!
//! Protocol (`diffphys-learn`): every `--data-seed` draws the training stream,
//! 64 validation and 128 held-out pairs from separate streams; every
//! `--train-seeds` entry trains every source once (initialisation and batch
//! order). Early stopping reads validation only; each trained network is
//! evaluated once on the held-out split. Default 3 data seeds × 3 training seeds.
//! Tutorial: docs/06-training-through-the-solver.md. Run:
//! `cargo run --release --example nn_solver_data` (`-- --small` for CI).

mod burgers_scene;
mod common;

use std::time::Instant;

use burgers_scene::{network, random_initial_state, Burgers, N};
use diffphys::learn::{
    mean_squared_error, select_best, Candidate, DataSeed, LearnError, LrSchedule, Pair, PairSource,
    Report, Split, Splits, SupervisedTrainer, TrainSeed, Trained, TrainedNet,
};
use diffphys::report::chart::{line_chart_svg, LineChart, Series};
use diffphys::report::progress_bar;
use ndarray::Axis;
use rand::rngs::StdRng;
use rand::Rng;
use serde_json::json;

type BoxError = Box<dyn std::error::Error>;

/// A pair drawn from `rng` and solved, and the seconds the solver took.
fn draw(scene: &Burgers, rng: &mut StdRng) -> Result<(Pair, f64), LearnError> {
    let u0 = random_initial_state(&scene.grid, rng);
    let start = Instant::now();
    let u16 = scene.observe_plain(&u0).map_err(|e| LearnError::Invalid {
        what: "Burgers solve",
        message: e.to_string(),
    })?;
    let seconds = start.elapsed().as_secs_f64();
    let sample = |a: ndarray::Array1<f64>| a.insert_axis(Axis(0)).into_dyn();
    Ok((
        Pair {
            input: sample(u0),
            target: sample(u16),
        },
        seconds,
    ))
}

/// Where a training's batches come from.
#[derive(Debug, Clone, Copy)]
enum Source {
    OnTheFly,
    Precomputed(usize),
}

impl Source {
    fn name(self) -> String {
        match self {
            Source::OnTheFly => "on_the_fly".into(),
            Source::Precomputed(n) => format!("precomputed_{n}"),
        }
    }
}

/// The solver as a data generator: a network learns the Burgers map from solver-made pairs.
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
        default_value_t = 1500,
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
    } = common::parse_args("nn_solver_data")?;
    let trainer = SupervisedTrainer {
        steps: iterations,
        batch: args.pick(16, 4),
        learning_rate: 2e-3,
        schedule: LrSchedule::Cosine {
            final_fraction: 0.05,
        },
        validate_every: args.pick(50, 10),
    };
    let set_sizes: Vec<usize> = args.pick(vec![64, 256, 1024], vec![8, 32]);
    let largest = set_sizes.iter().copied().max().unwrap_or(0);
    let [validation_n, held_out_n] = args.pick([64, 128], [8, 8]);
    let scene = Burgers::new()?;
    let (_, net) = network(0)?; // the layout; every training's parameters are its own
    let mut sources = vec![Source::OnTheFly];
    sources.extend(set_sizes.iter().map(|&n| Source::Precomputed(n)));

    let (mut held_out, mut validation) = (Report::new(), Report::new());
    let mut curves: Vec<(String, Vec<(usize, f64)>)> = Vec::new();
    let (mut solver_seconds, mut solved) = (0.0, 0usize);
    let (mut data_seconds_on_the_fly, mut network_seconds, mut trainings) = (0.0, 0.0, 0usize);
    for &ds in &seeds.data {
        // The training split is the largest fixed set: the first pairs of the
        // training stream, which the on-the-fly source draws afresh.
        let splits = Splits::generate(
            DataSeed(ds),
            [largest, validation_n, held_out_n],
            |_, n, rng| {
                (0..n)
                    .map(|_| {
                        draw(&scene, rng).map(|(p, s)| {
                            solver_seconds += s;
                            p
                        })
                    })
                    .collect::<Result<Vec<_>, _>>()
            },
        )?;
        solved += largest + validation_n + held_out_n;
        let zero = splits.held_out().evaluate_baseline(|d| {
            Ok(d.iter()
                .map(|p| p.target.mapv(|v| v * v).mean().unwrap_or(0.0))
                .sum::<f64>()
                / d.len() as f64)
        })?;
        held_out.add("zero_network", ds, None, zero);
        for &source in &sources {
            let mut group = Vec::new();
            for &ts in &seeds.train {
                let (params, _) = network(TrainSeed(ts).init_rng().random())?;
                let bar = progress_bar(
                    trainer.steps,
                    &format!("data {ds} {} seed {ts}", source.name()),
                );
                let mut stream_seconds = 0.0;
                let mut stream = |rng: &mut StdRng| {
                    draw(&scene, rng).map(|(p, s)| {
                        stream_seconds += s;
                        p
                    })
                };
                let (pairs, mut rng) = match source {
                    Source::OnTheFly => (
                        PairSource::Stream(&mut stream),
                        DataSeed(ds).rng(Split::Train),
                    ),
                    Source::Precomputed(n) => (
                        PairSource::Fixed(&splits.train[..n]),
                        TrainSeed(ts).sampling_rng(),
                    ),
                };
                let t =
                    trainer.train(&net, params, pairs, &mut rng, &splits.validation, &|| {
                        bar.inc(1)
                    })?;
                bar.finish_and_clear();
                if let Source::OnTheFly = source {
                    (solver_seconds, solved) = (
                        solver_seconds + stream_seconds,
                        solved + trainer.steps * trainer.batch,
                    );
                    data_seconds_on_the_fly += t.model.seconds_data;
                }
                (network_seconds, trainings) =
                    (network_seconds + t.model.seconds_network, trainings + 1);
                println!(
                    "  {:>16}, train seed {ts}: network {:.1} s, data {:.2} s; validation {:.4e} (kept step {})",
                    source.name(), t.model.seconds_network, t.model.seconds_data, t.model.validation, t.model.best_step
                );
                validation.add(&source.name(), ds, Some(ts), t.model.validation);
                group.push(t);
            }
            // Nothing to choose between sources; early stopping chose each
            // network's step on validation. Held-out: each network once.
            let v = group.iter().map(|t| t.model.validation).sum::<f64>() / group.len() as f64;
            let selection =
                select_best(vec![Candidate::new(source.name(), Trained::new(group), v)])?;
            for model in selection.models {
                let e =
                    splits
                        .held_out()
                        .evaluate(model, |group: &Vec<Trained<TrainedNet>>, d| {
                            group
                                .iter()
                                .map(|t| mean_squared_error(&net, &t.model.params, d))
                                .collect::<Result<Vec<_>, _>>()
                        })?;
                for ((&error, &ts), t) in e.result.iter().zip(&seeds.train).zip(&e.model) {
                    held_out.add(&e.label, ds, Some(ts), error);
                    if ts == seeds.train[0] && ds == seeds.data[0] {
                        curves.push((e.label.clone(), t.model.validation_curve.clone()));
                    }
                }
            }
        }
    }

    println!("\nheld-out mean squared error (data seeds {:?} × train seeds {:?}, {held_out_n} pairs each):", seeds.data, seeds.train);
    print!("{}", held_out.table(Some("on_the_fly")));
    let step_seconds = network_seconds / (trainings * trainer.steps) as f64;
    let data_per_step =
        data_seconds_on_the_fly / (seeds.data.len() * seeds.train.len() * trainer.steps) as f64;
    let samples_per_second = solved as f64 / solver_seconds;
    println!(
        "solver: {samples_per_second:.0} samples per second; one training step (batch {}): {:.2} ms in the \
         network, {:.2} ms drawing and solving its batch on the fly ({:.1}% of the step)",
        trainer.batch, 1e3 * step_seconds, 1e3 * data_per_step, 100.0 * data_per_step / (step_seconds + data_per_step)
    );
    let series: Vec<Series> = curves
        .iter()
        .map(|(name, c)| {
            Series::new(
                name.clone(),
                c.iter().map(|&(s, e)| (s as f64, e)).collect(),
            )
        })
        .collect();
    line_chart_svg(
        &args.out.join("validation_error.svg"),
        &LineChart {
            title: "Validation error during training (first data seed and training seed)",
            x_label: "training step",
            y_label: "validation mean squared error",
            log_x: false,
            log_y: true,
            series: &series,
        },
    )?;
    println!("chart written to {}", args.out.display());
    common::print_json_line(&json!({
        "example": "nn_solver_data",
        "small": args.small,
        "cells": N,
        "data_seeds": seeds.data,
        "train_seeds": seeds.train,
        "training_steps": trainer.steps,
        "batch": trainer.batch,
        "held_out_per_data_seed": held_out_n,
        "held_out_mse": held_out.to_json(),
        "validation_mse": validation.to_json(),
        "selected_k": null,
        "selected_by": "validation",
        "selection": "early stopping (the kept step of every training) on the validation split; no unroll to choose",
        "samples_per_second_solver": samples_per_second,
        "seconds_per_training_step": step_seconds,
        "seconds_data_per_step_on_the_fly": data_per_step,
        "peak_rss_bytes": common::peak_rss_bytes(),
        "seconds": run_start.elapsed().as_secs_f64(),
    }));
    Ok(())
}
