//! The solver as a data generator (solver → network): a 1D U-Net learns the map
//! from the initial state of the Burgers scene of `burgers_inverse` to its state
//! after step 16, from pairs the solver produces.
//!
//! The same network, from the same initial parameters, is trained for the same
//! number of steps on (a) samples drawn afresh by the solver at every step and
//! (b) fixed data sets of 64, 256 and 1024 samples computed once. The held-out
//! error comes from another seed; the solver's throughput is set against the
//! cost of one training step.
//!
//! Tutorial: docs/06-training-through-the-solver.md. Run:
//! `cargo run --release --example nn_solver_data` (`-- --small` for CI).

mod burgers_scene;
mod common;

use std::time::Instant;

use burgers_scene::{
    batch_of, curve, learning_rate, mse, network, random_initial_state, sample_of, BoxError,
    Burgers, N,
};
use diffphys_compare::chart::{line_chart_svg, LineChart, Series};
use diffphys_compare::harness::progress_bar;
use diffphys::nn::{check_loss, Layer, Params, UNet};
use diffphys::prelude::*;
use ndarray::Array1;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Seeds: training data (on the fly and precomputed), held-out data, initial
/// parameters, batch order.
const TRAIN_SEED: u64 = 11;
const HELDOUT_SEED: u64 = 12;
const MODEL_SEED: u64 = 13;
const BATCH_SEED: u64 = 14;
/// Widths of the U-Net, finest first (the same network as `nn_control_burgers`).
/// Adam's initial step size, the same for every run (cosine decay to 1/20).
const ADAM_RATE: f64 = 2e-3;

/// Pairs (initial state, state after step 16), and the seconds the solver took
/// to make them.
struct Pairs {
    input: Vec<Array1<f64>>,
    target: Vec<Array1<f64>>,
    seconds_solver: f64,
}

impl Pairs {
    fn new() -> Self {
        Pairs {
            input: Vec::new(),
            target: Vec::new(),
            seconds_solver: 0.0,
        }
    }

    /// Adds `count` pairs drawn from `rng` and solved.
    fn extend(
        &mut self,
        scene: &Burgers,
        count: usize,
        rng: &mut impl Rng,
    ) -> Result<(), BoxError> {
        for _ in 0..count {
            let u0 = random_initial_state(&scene.grid, rng);
            let start = Instant::now();
            self.target.push(scene.observe_plain(&u0)?);
            self.seconds_solver += start.elapsed().as_secs_f64();
            self.input.push(u0);
        }
        Ok(())
    }

    fn draw(scene: &Burgers, count: usize, seed: u64) -> Result<Self, BoxError> {
        let mut pairs = Pairs::new();
        pairs.extend(scene, count, &mut StdRng::seed_from_u64(seed))?;
        Ok(pairs)
    }

    fn len(&self) -> usize {
        self.input.len()
    }
}

/// Where a training step's batch comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Source {
    /// Drawn and solved afresh at every step.
    OnTheFly,
    /// Picked at random from a fixed set of this many pairs.
    Precomputed(usize),
}

impl Source {
    fn label(self) -> String {
        match self {
            Source::OnTheFly => "on the fly".to_string(),
            Source::Precomputed(n) => format!("precomputed {n}"),
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Budget {
    steps: usize,
    batch: usize,
    eval_every: usize,
}

struct Run {
    source: Source,
    /// Held-out error, and the mean training loss since the previous
    /// evaluation, against the training step.
    heldout: Vec<(usize, f64)>,
    training: Vec<(usize, f64)>,
    /// Seconds in the network's forward, backward and update, and in making
    /// data (solving fresh pairs, or copying pairs out of the set).
    seconds_network: f64,
    seconds_data: f64,
    /// Of `seconds_data`, the seconds in the solver (on the fly only).
    seconds_solver: f64,
    samples_seen: usize,
    /// The trained network's outputs on the held-out inputs, `[cases, 1, N]`.
    predictions: ArrayD<f64>,
}

/// The mean squared error of the network over `pairs`.
fn heldout_error(net: &UNet, params: &Params<f64>, pairs: &Pairs) -> Result<f64, BoxError> {
    let tape = Tape::new();
    let p = params.bind(&tape);
    let x = tape.constant(batch_of(&pairs.input.iter().collect::<Vec<_>>()));
    let y = net.forward(&p, x)?;
    let y = y.value();
    let total: f64 = (0..pairs.len())
        .map(|b| mse(&sample_of(&y, b), &pairs.target[b]))
        .sum();
    Ok(total / pairs.len() as f64)
}

fn train(
    scene: &Burgers,
    source: Source,
    precomputed: &Pairs,
    heldout: &Pairs,
    budget: Budget,
) -> Result<Run, BoxError> {
    let (mut params, net) = network(MODEL_SEED)?;
    let mut adam = Adam::new(ADAM_RATE);
    let mut batches = StdRng::seed_from_u64(BATCH_SEED);
    // On the fly, the data stream starts where the precomputed sets start too.
    let mut fresh_rng = StdRng::seed_from_u64(TRAIN_SEED);
    let mut run = Run {
        source,
        heldout: Vec::new(),
        training: Vec::new(),
        seconds_network: 0.0,
        seconds_data: 0.0,
        seconds_solver: 0.0,
        samples_seen: 0,
        predictions: ArrayD::zeros(vec![0]),
    };
    let mut window = (0.0, 0usize);
    let bar = progress_bar(budget.steps, &source.label());
    for step in 0..=budget.steps {
        if step % budget.eval_every == 0 || step == budget.steps {
            let error = heldout_error(&net, &params, heldout)?;
            run.heldout.push((step, error));
            if window.1 > 0 {
                run.training.push((step, window.0 / window.1 as f64));
            }
            window = (0.0, 0);
            bar.set_message(format!("held-out error {error:.3e}"));
        }
        if step == budget.steps {
            break;
        }
        let start = Instant::now();
        let (input, target) = match source {
            Source::OnTheFly => {
                let mut fresh = Pairs::new();
                fresh.extend(scene, budget.batch, &mut fresh_rng)?;
                run.seconds_solver += fresh.seconds_solver;
                (
                    batch_of(&fresh.input.iter().collect::<Vec<_>>()),
                    batch_of(&fresh.target.iter().collect::<Vec<_>>()),
                )
            }
            Source::Precomputed(n) => {
                let picks: Vec<usize> = (0..budget.batch)
                    .map(|_| batches.random_range(0..n))
                    .collect();
                (
                    batch_of(
                        &picks
                            .iter()
                            .map(|&i| &precomputed.input[i])
                            .collect::<Vec<_>>(),
                    ),
                    batch_of(
                        &picks
                            .iter()
                            .map(|&i| &precomputed.target[i])
                            .collect::<Vec<_>>(),
                    ),
                )
            }
        };
        run.samples_seen += budget.batch;
        let made = Instant::now();
        run.seconds_data += (made - start).as_secs_f64();
        adam.lr = learning_rate(ADAM_RATE, step, budget.steps);
        let tape = Tape::new();
        let p = params.bind(&tape);
        let y = net.forward(&p, tape.constant(input))?;
        let loss = y.sub(tape.constant(target))?.powi(2)?.mean()?;
        let value = check_loss(step, loss.item()?)?;
        let grads = tape.backward(loss, p.vars())?;
        params.step(&mut adam, &grads, &p)?;
        run.seconds_network += made.elapsed().as_secs_f64();
        window = (window.0 + value, window.1 + 1);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let tape = Tape::new();
    let x = tape.constant(batch_of(&heldout.input.iter().collect::<Vec<_>>()));
    run.predictions = net.forward(&params.bind(&tape), x)?.to_array();
    Ok(run)
}

fn main() -> Result<(), BoxError> {
    let args = common::ExampleArgs::parse("nn_solver_data")?;
    let budget = Budget {
        steps: args.iterations.unwrap_or(args.pick(1500, 20)),
        batch: args.pick(16, 4),
        eval_every: args.pick(50, 10),
    };
    let sizes: Vec<usize> = args.pick(vec![64, 256, 1024], vec![8, 32]);
    let heldout_count = args.pick(128, 8);
    let scene = Burgers::new()?;

    // The largest set, solved once; the smaller ones are its first samples.
    let largest = sizes.iter().copied().max().unwrap_or(0);
    let start = Instant::now();
    let precomputed = Pairs::draw(&scene, largest, TRAIN_SEED)?;
    let seconds_precompute = start.elapsed().as_secs_f64();
    let heldout = Pairs::draw(&scene, heldout_count, HELDOUT_SEED)?;
    let heldout_error_zero = heldout
        .target
        .iter()
        .map(|t| mse(t, &Array1::zeros(N)))
        .sum::<f64>()
        / heldout.len() as f64;
    println!(
        "Burgers, {N} cells, u0 → u(step 16): {largest} pairs drawn and solved in {:.3} s; \
         {} held-out pairs (seed {HELDOUT_SEED}), zero-network error \
         {heldout_error_zero:.4e}",
        seconds_precompute,
        heldout.len()
    );

    let mut runs = Vec::new();
    let sources =
        std::iter::once(Source::OnTheFly).chain(sizes.iter().map(|&n| Source::Precomputed(n)));
    for source in sources {
        let run = train(&scene, source, &precomputed, &heldout, budget)?;
        println!(
            "{:>16}: {} steps of batch {} ({} samples seen), network {:.1} s, data {:.2} s; \
             final training loss {:.3e}, held-out error {:.3e}",
            source.label(),
            budget.steps,
            budget.batch,
            run.samples_seen,
            run.seconds_network,
            run.seconds_data,
            run.training.last().map_or(f64::NAN, |t| t.1),
            run.heldout.last().map_or(f64::NAN, |h| h.1),
        );
        runs.push(run);
    }

    let steps = budget.steps.max(1) as f64;
    let seconds_per_training_step =
        runs.iter().map(|r| r.seconds_network).sum::<f64>() / (steps * runs.len() as f64);
    let on_the_fly = &runs[0];
    let seconds_data_per_step_on_the_fly = on_the_fly.seconds_data / steps;
    // Throughput over every pair the solver made: the sets and the stream.
    let samples_per_second_solver = (largest + on_the_fly.samples_seen) as f64
        / (precomputed.seconds_solver + on_the_fly.seconds_solver);
    let final_error = |r: &Run| r.heldout.last().map_or(f64::NAN, |h| h.1);
    let best_error = |r: &Run| r.heldout.iter().map(|h| h.1).fold(f64::INFINITY, f64::min);
    println!(
        "solver: {samples_per_second_solver:.0} samples per second; one training step (batch \
         {}): {:.2} ms in the network; drawing and solving its batch afresh: {:.2} ms ({:.1}% \
         of the step)",
        budget.batch,
        1e3 * seconds_per_training_step,
        1e3 * seconds_data_per_step_on_the_fly,
        100.0 * seconds_data_per_step_on_the_fly
            / (seconds_per_training_step + seconds_data_per_step_on_the_fly),
    );
    println!(
        "held-out error after {} steps (best during training):",
        budget.steps
    );
    for r in &runs {
        println!(
            "{:>16}: {:.4e} ({:.4e})",
            r.source.label(),
            final_error(r),
            best_error(r)
        );
    }

    let mut heldout_series: Vec<Series> = runs
        .iter()
        .map(|r| curve(&r.source.label(), &r.heldout))
        .collect();
    heldout_series.push(Series::new(
        "zero network",
        vec![(0.0, heldout_error_zero), (steps, heldout_error_zero)],
    ));
    let training_series: Vec<Series> = runs
        .iter()
        .map(|r| curve(&r.source.label(), &r.training))
        .collect();
    let files = [
        args.out.join("heldout_error.svg"),
        args.out.join("training_loss.svg"),
    ];
    line_chart_svg(
        &files[0],
        &LineChart {
            title: "Held-out error mean((net(u0) - u16)^2) during training",
            x_label: "training step",
            y_label: "held-out mean squared error",
            log_x: false,
            log_y: true,
            series: &heldout_series,
        },
    )?;
    line_chart_svg(
        &files[1],
        &LineChart {
            title: "Training loss (mean over the steps since the last evaluation)",
            x_label: "training step",
            y_label: "training mean squared error",
            log_x: false,
            log_y: true,
            series: &training_series,
        },
    )?;
    for f in &files {
        println!("wrote {}", f.display());
    }

    let precomputed_errors: serde_json::Map<String, serde_json::Value> = runs
        .iter()
        .filter_map(|r| match r.source {
            Source::Precomputed(n) => Some((n.to_string(), final_error(r).into())),
            Source::OnTheFly => None,
        })
        .collect();
    let precomputed_best: serde_json::Map<String, serde_json::Value> = runs
        .iter()
        .filter_map(|r| match r.source {
            Source::Precomputed(n) => Some((n.to_string(), best_error(r).into())),
            Source::OnTheFly => None,
        })
        .collect();
    let stacked = |rows: &[Array1<f64>]| -> Result<ArrayD<f64>, BoxError> {
        let views: Vec<_> = rows.iter().map(|r| r.view()).collect();
        Ok(ndarray::stack(ndarray::Axis(0), &views)?.into_dyn())
    };
    let (inputs, targets) = (stacked(&heldout.input)?, stacked(&heldout.target)?);
    let mut npy = vec![
        (
            "heldout_u0",
            inputs.view(),
            "held-out initial states [cases, 128]".to_string(),
        ),
        (
            "heldout_u16",
            targets.view(),
            "their solver states at step 16 [cases, 128]".to_string(),
        ),
    ];
    let names: Vec<String> = runs
        .iter()
        .map(|r| format!("prediction_{}", r.source.label().replace(' ', "_")))
        .collect();
    for (r, name) in runs.iter().zip(&names) {
        npy.push((
            name.as_str(),
            r.predictions.view(),
            format!(
                "the network trained on {} data, on the held-out states [cases, 1, 128]",
                r.source.label()
            ),
        ));
    }
    args.write_npy(
        &npy.iter()
            .map(|(n, a, m)| (*n, a.view(), m.as_str()))
            .collect::<Vec<_>>(),
    )?;

    common::print_json_line(&serde_json::json!({
        "example": "nn_solver_data",
        "training_steps": budget.steps,
        "batch": budget.batch,
        "heldout_cases": heldout.len(),
        "samples_seen_on_the_fly": on_the_fly.samples_seen,
        "heldout_error_zero": heldout_error_zero,
        "heldout_error_on_the_fly": final_error(on_the_fly),
        "heldout_error_precomputed": precomputed_errors,
        "best_heldout_error_on_the_fly": best_error(on_the_fly),
        "best_heldout_error_precomputed": precomputed_best,
        "samples_per_second_solver": samples_per_second_solver,
        "seconds_per_training_step": seconds_per_training_step,
        "seconds_data_per_step_on_the_fly": seconds_data_per_step_on_the_fly,
        "seconds_precompute_largest_set": seconds_precompute,
        "final_training_loss": runs
            .iter()
            .map(|r| (r.source.label(), r.training.last().map_or(f64::NAN, |t| t.1).into()))
            .collect::<serde_json::Map<String, serde_json::Value>>(),
    }));
    Ok(())
}
