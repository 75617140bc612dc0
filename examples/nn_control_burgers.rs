//! A network produces the solver's input (network → solver): from the observed
//! state of the Burgers scene of `burgers_inverse` (the state after step 16), a
//! 1D U-Net predicts the initial state.
//!
//! The same network, from the same initial parameters, on the same batches, is
//! trained two ways: through the solver (differentiable physics), with the loss
//! `mean((P(net(obs)) − obs)²)` where `P` is the 16 recorded solver steps, and
//! supervised, with `mean((net(obs) − u₀)²)` on the known initial states. On
//! held-out cases from another seed both are compared with a zero initial state,
//! with per-instance optimisation (the 50 gradient-descent steps of
//! `burgers_inverse` on each case) and with the network's prediction refined by
//! 5 of those steps.
//!
//! Tutorial: docs/06-training-through-the-solver.md. Run:
//! `cargo run --release --example nn_control_burgers` (`-- --small` for CI).

mod burgers_scene;
mod common;

use std::path::{Path, PathBuf};
use std::time::Instant;

use burgers_scene::{
    batch_of, curve, learning_rate, mse, network, random_initial_state, sample_of, BoxError,
    Burgers, DESCENT_RATE, N,
};
use diffphys::nn::{check_loss, Layer, Params, UNet};
use diffphys::prelude::*;
use diffphys_compare::chart::{line_chart_svg, LineChart, Series};
use diffphys_compare::harness::progress_bar;
use ndarray::Array1;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Seeds: training set, held-out set, initial parameters, batch order.
const TRAIN_SEED: u64 = 1;
const HELDOUT_SEED: u64 = 2;
const MODEL_SEED: u64 = 3;
const BATCH_SEED: u64 = 4;
/// Widths of the U-Net, finest first (three poolings: it sees the whole field).
/// Adam's initial step size, the same for both trainings (cosine decay to 1/20).
const ADAM_RATE: f64 = 2e-3;
/// Per-instance optimisation: the gradient-descent steps of `burgers_inverse`,
/// and the steps that refine a network's prediction.
const PER_INSTANCE_STEPS: usize = 50;
const REFINE_STEPS: usize = 5;

/// Initial states and their observations.
struct Cases {
    u0: Vec<Array1<f64>>,
    obs: Vec<Array1<f64>>,
}

impl Cases {
    fn draw(scene: &Burgers, count: usize, seed: u64) -> Result<Self, BoxError> {
        let mut rng = StdRng::seed_from_u64(seed);
        let u0: Vec<_> = (0..count)
            .map(|_| random_initial_state(&scene.grid, &mut rng))
            .collect();
        let obs = u0
            .iter()
            .map(|u| scene.observe_plain(u))
            .collect::<Result<_, _>>()?;
        Ok(Cases { u0, obs })
    }

    fn len(&self) -> usize {
        self.u0.len()
    }
}

/// What a network is trained on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Training {
    /// Through the solver: `mean((P(net(obs)) − obs)²)`.
    Physics,
    /// On the known initial states: `mean((net(obs) − u₀)²)`.
    Supervised,
}

impl Training {
    fn label(self) -> &'static str {
        match self {
            Training::Physics => "differentiable physics",
            Training::Supervised => "supervised",
        }
    }
}

/// The training budget, the same for both trainings.
#[derive(Debug, Clone, Copy)]
struct Budget {
    steps: usize,
    batch: usize,
    eval_every: usize,
}

/// A trained network and its record.
struct Run {
    net: UNet,
    params: Params<f64>,
    /// Held-out physics loss and initial-state error against the training step.
    heldout_physics: Vec<(usize, f64)>,
    heldout_u0_error: Vec<(usize, f64)>,
    final_training_loss: f64,
    seconds: f64,
}

/// The network's initial states for a `[batch, 1, N]` batch of observations.
fn predict(net: &UNet, params: &Params<f64>, obs: &ArrayD<f64>) -> Result<ArrayD<f64>, BoxError> {
    let tape = Tape::new();
    let p = params.bind(&tape);
    let y = net.forward(&p, tape.constant(obs.clone()))?;
    Ok(y.to_array())
}

/// Held-out physics loss and initial-state error of predicted initial states.
fn score(scene: &Burgers, cases: &Cases, u0: &[Array1<f64>]) -> Result<(f64, f64), BoxError> {
    let mut physics = 0.0;
    let mut u0_error = 0.0;
    for ((u, truth), obs) in u0.iter().zip(&cases.u0).zip(&cases.obs) {
        physics += mse(&scene.observe_plain(u)?, obs);
        u0_error += mse(u, truth);
    }
    let n = cases.len() as f64;
    Ok((physics / n, u0_error / n))
}

fn network_predictions(
    net: &UNet,
    params: &Params<f64>,
    cases: &Cases,
) -> Result<Vec<Array1<f64>>, BoxError> {
    let obs = batch_of(&cases.obs.iter().collect::<Vec<_>>());
    let pred = predict(net, params, &obs)?;
    Ok((0..cases.len()).map(|b| sample_of(&pred, b)).collect())
}

fn train(
    scene: &Burgers,
    training: Training,
    data: &Cases,
    heldout: &Cases,
    budget: Budget,
) -> Result<Run, BoxError> {
    let (mut params, net) = network(MODEL_SEED)?;
    let mut batches = StdRng::seed_from_u64(BATCH_SEED);
    let mut adam = Adam::new(ADAM_RATE);
    let mut heldout_physics = Vec::new();
    let mut heldout_u0_error = Vec::new();
    let mut final_training_loss = f64::NAN;
    let bar = progress_bar(budget.steps, training.label());
    let mut seconds = 0.0;
    for step in 0..=budget.steps {
        if step % budget.eval_every == 0 || step == budget.steps {
            let (physics, u0_error) = score(
                scene,
                heldout,
                &network_predictions(&net, &params, heldout)?,
            )?;
            heldout_physics.push((step, physics));
            heldout_u0_error.push((step, u0_error));
            bar.set_message(format!("held-out physics loss {physics:.3e}"));
        }
        if step == budget.steps {
            break;
        }
        let start = Instant::now();
        let picks: Vec<usize> = (0..budget.batch)
            .map(|_| batches.random_range(0..data.len()))
            .collect();
        adam.lr = learning_rate(ADAM_RATE, step, budget.steps);
        let tape = Tape::new();
        let p = params.bind(&tape);
        let obs = tape.constant(batch_of(
            &picks.iter().map(|&i| &data.obs[i]).collect::<Vec<_>>(),
        ));
        let pred = net.forward(&p, obs)?;
        let residual = match training {
            Training::Physics => scene.observe_batch(pred)?.sub(obs)?,
            Training::Supervised => {
                let u0 = batch_of(&picks.iter().map(|&i| &data.u0[i]).collect::<Vec<_>>());
                pred.sub(tape.constant(u0))?
            }
        };
        let loss = residual.powi(2)?.mean()?;
        final_training_loss = check_loss(step, loss.item()?)?;
        let grads = tape.backward(loss, p.vars())?;
        params.step(&mut adam, &grads, &p)?;
        seconds += start.elapsed().as_secs_f64();
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(Run {
        net,
        params,
        heldout_physics,
        heldout_u0_error,
        final_training_loss,
        seconds,
    })
}

/// Per-instance gradient descent from each of `starts`; returns the results and
/// the seconds per case.
fn descend_all(
    scene: &Burgers,
    cases: &Cases,
    starts: &[Array1<f64>],
    iterations: usize,
) -> Result<(Vec<Array1<f64>>, f64), BoxError> {
    let start = Instant::now();
    let out = starts
        .iter()
        .zip(&cases.obs)
        .map(|(u, obs)| scene.descend(u, obs, iterations))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((out, start.elapsed().as_secs_f64() / cases.len() as f64))
}

/// How gradient descent behaves from `starts`: the held-out physics loss before
/// each step and after the last, the loss of the best iterate of each case, the
/// mean gradient norm at the start, and the cases whose loss ends higher than it
/// began.
struct Descent {
    losses: Vec<f64>,
    best: f64,
    gradient_norm: f64,
    cases_worse: usize,
}

fn trace_descent(
    scene: &Burgers,
    cases: &Cases,
    starts: &[Array1<f64>],
    iterations: usize,
) -> Result<Descent, BoxError> {
    let mut losses = vec![0.0; iterations + 1];
    let mut gradient_norm = 0.0;
    let mut cases_worse = 0;
    let mut best = 0.0;
    for (u0, obs) in starts.iter().zip(&cases.obs) {
        let mut u = u0.clone();
        let mut first = f64::NAN;
        let mut lowest = f64::INFINITY;
        for (k, total) in losses.iter_mut().enumerate() {
            let (loss, g) = scene.loss_and_gradient(&u, obs)?;
            *total += loss;
            lowest = lowest.min(loss);
            if k == 0 {
                first = loss;
                gradient_norm += g.dot(&g).sqrt();
            } else if k == iterations && loss > first {
                cases_worse += 1;
            }
            u.scaled_add(-DESCENT_RATE, &g);
        }
        best += lowest;
    }
    let n = cases.len() as f64;
    Ok(Descent {
        losses: losses.iter().map(|l| l / n).collect(),
        best: best / n,
        gradient_norm: gradient_norm / n,
        cases_worse,
    })
}

/// A horizontal line across `steps` for a baseline in a chart.
fn level(label: &str, steps: usize, value: f64) -> Series {
    Series::new(label, vec![(0.0, value), (steps as f64, value)])
}

#[allow(clippy::too_many_arguments)]
fn write_charts(
    out: &Path,
    scene: &Burgers,
    runs: &[(Training, &Run)],
    steps: usize,
    baselines: &[(&str, f64)],
    shown: [(&str, &Array1<f64>); 4],
) -> Result<Vec<PathBuf>, BoxError> {
    let mut files = Vec::new();
    let mut save = |name: &str| {
        let p = out.join(name);
        files.push(p.clone());
        p
    };
    let mut physics: Vec<Series> = runs
        .iter()
        .map(|(t, r)| curve(t.label(), &r.heldout_physics))
        .collect();
    physics.extend(baselines.iter().map(|(l, v)| level(l, steps, *v)));
    line_chart_svg(
        &save("heldout_physics_loss.svg"),
        &LineChart {
            title: "Held-out physics loss mean((P(net(obs)) - obs)^2) during training",
            x_label: "training step",
            y_label: "held-out physics loss",
            log_x: false,
            log_y: true,
            series: &physics,
        },
    )?;
    let u0_error: Vec<Series> = runs
        .iter()
        .map(|(t, r)| curve(t.label(), &r.heldout_u0_error))
        .collect();
    line_chart_svg(
        &save("heldout_u0_error.svg"),
        &LineChart {
            title: "Held-out initial-state error mean((net(obs) - u0)^2) during training",
            x_label: "training step",
            y_label: "held-out initial-state error",
            log_x: false,
            log_y: true,
            series: &u0_error,
        },
    )?;
    let x = scene.grid.centers();
    let along_x = |label: String, v: &Array1<f64>| {
        Series::new(label, x.iter().copied().zip(v.iter().copied()).collect())
    };
    let initial: Vec<Series> = shown
        .iter()
        .map(|(label, u)| along_x(label.to_string(), u))
        .collect();
    line_chart_svg(
        &save("heldout_case_initial.svg"),
        &LineChart {
            title: "Held-out case 0: initial state u(t=0)",
            x_label: "x",
            y_label: "u",
            log_x: false,
            log_y: false,
            series: &initial,
        },
    )?;
    let observed = shown
        .iter()
        .map(|(label, u)| {
            let label = if *label == "true u0" {
                "observed u(t=0.5)".to_string()
            } else {
                format!("P({label})")
            };
            Ok(along_x(label, &scene.observe_plain(u)?))
        })
        .collect::<Result<Vec<_>, BoxError>>()?;
    line_chart_svg(
        &save("heldout_case_observed.svg"),
        &LineChart {
            title: "Held-out case 0: state at t = 0.5 from each initial state",
            x_label: "x",
            y_label: "u",
            log_x: false,
            log_y: false,
            series: &observed,
        },
    )?;
    Ok(files)
}

fn main() -> Result<(), BoxError> {
    let args = common::ExampleArgs::parse("nn_control_burgers")?;
    let budget = Budget {
        steps: args.iterations.unwrap_or(args.pick(3000, 20)),
        batch: args.pick(16, 4),
        eval_every: args.pick(50, 10),
    };
    let (train_count, heldout_count) = args.pick((1024, 64), (32, 8));
    let scene = Burgers::new()?;
    let data = Cases::draw(&scene, train_count, TRAIN_SEED)?;
    let heldout = Cases::draw(&scene, heldout_count, HELDOUT_SEED)?;
    println!(
        "Burgers, {N} cells, observed after 16 steps; {train_count} training cases (seed \
         {TRAIN_SEED}), {heldout_count} held-out cases (seed {HELDOUT_SEED})"
    );

    let mut runs = Vec::new();
    for training in [Training::Physics, Training::Supervised] {
        let run = train(&scene, training, &data, &heldout, budget)?;
        println!(
            "{:>22}: {} steps of batch {} in {:.1} s ({:.1} ms per step), final training \
             loss {:.3e}, held-out physics loss {:.3e}",
            training.label(),
            budget.steps,
            budget.batch,
            run.seconds,
            1e3 * run.seconds / budget.steps.max(1) as f64,
            run.final_training_loss,
            run.heldout_physics.last().map_or(f64::NAN, |p| p.1),
        );
        runs.push((training, run));
    }
    let (dp, supervised) = (&runs[0].1, &runs[1].1);

    let start = Instant::now();
    let dp_u0 = network_predictions(&dp.net, &dp.params, &heldout)?;
    let seconds_per_case_network = start.elapsed().as_secs_f64() / heldout.len() as f64;
    let supervised_u0 = network_predictions(&supervised.net, &supervised.params, &heldout)?;
    let zeros = vec![Array1::zeros(N); heldout.len()];
    let (per_instance_u0, seconds_per_case_per_instance) =
        descend_all(&scene, &heldout, &zeros, PER_INSTANCE_STEPS)?;
    let (warm_u0, seconds_refine) = descend_all(&scene, &heldout, &dp_u0, REFINE_STEPS)?;
    let (warm_supervised_u0, _) = descend_all(&scene, &heldout, &supervised_u0, REFINE_STEPS)?;
    let seconds_per_case_warm_started = seconds_per_case_network + seconds_refine;

    let (loss_dp, u0_err_dp) = score(&scene, &heldout, &dp_u0)?;
    let (loss_supervised, u0_err_supervised) = score(&scene, &heldout, &supervised_u0)?;
    let (loss_zero, u0_err_zero) = score(&scene, &heldout, &zeros)?;
    let (loss_per_instance, u0_err_per_instance) = score(&scene, &heldout, &per_instance_u0)?;
    let (loss_warm, u0_err_warm) = score(&scene, &heldout, &warm_u0)?;
    let (loss_warm_supervised, u0_err_warm_supervised) =
        score(&scene, &heldout, &warm_supervised_u0)?;

    println!(
        "held-out ({} cases)                 physics loss   u0 error   s per case",
        heldout.len()
    );
    let rows = [
        ("zero initial state", loss_zero, u0_err_zero, 0.0),
        (
            "network, differentiable physics",
            loss_dp,
            u0_err_dp,
            seconds_per_case_network,
        ),
        (
            "network, supervised",
            loss_supervised,
            u0_err_supervised,
            seconds_per_case_network,
        ),
        (
            "per-instance, 50 GD steps",
            loss_per_instance,
            u0_err_per_instance,
            seconds_per_case_per_instance,
        ),
        (
            "DP network + 5 GD steps",
            loss_warm,
            u0_err_warm,
            seconds_per_case_warm_started,
        ),
        (
            "supervised network + 5 GD steps",
            loss_warm_supervised,
            u0_err_warm_supervised,
            seconds_per_case_warm_started,
        ),
    ];
    for (label, loss, err, seconds) in rows {
        println!("{label:>32}   {loss:.4e}    {err:.4e}   {seconds:.2e}");
    }

    println!(
        "gradient descent (rate {DESCENT_RATE}) from each start: mean held-out physics loss \
         before steps 1..{REFINE_STEPS} and after, mean |gradient| at the start"
    );
    let mut descents = serde_json::Map::new();
    for (label, starts) in [
        ("zero", &zeros),
        ("dp", &dp_u0),
        ("supervised", &supervised_u0),
    ] {
        let d = trace_descent(&scene, &heldout, starts, REFINE_STEPS)?;
        let losses: Vec<String> = d.losses.iter().map(|l| format!("{l:.3e}")).collect();
        println!(
            "{label:>11}: {}; best iterate {:.3e}; |gradient| {:.3e}; loss higher after \
             {REFINE_STEPS} steps in {} of {} cases",
            losses.join(" "),
            d.best,
            d.gradient_norm,
            d.cases_worse,
            heldout.len()
        );
        descents.insert(
            label.to_string(),
            serde_json::json!({
                "losses": d.losses,
                "best_iterate": d.best,
                "gradient_norm": d.gradient_norm,
                "cases_worse": d.cases_worse,
            }),
        );
    }

    let shown = [
        ("true u0", &heldout.u0[0]),
        ("DP network", &dp_u0[0]),
        ("supervised network", &supervised_u0[0]),
        ("per-instance (50 GD)", &per_instance_u0[0]),
    ];
    let baselines = [
        ("zero initial state", loss_zero),
        ("per-instance, 50 GD steps", loss_per_instance),
    ];
    let runs_ref: Vec<(Training, &Run)> = runs.iter().map(|(t, r)| (*t, r)).collect();
    for f in write_charts(
        &args.out,
        &scene,
        &runs_ref,
        budget.steps,
        &baselines,
        shown,
    )? {
        println!("wrote {}", f.display());
    }
    let stacked = |rows: &[Array1<f64>]| -> Result<ArrayD<f64>, BoxError> {
        let views: Vec<_> = rows.iter().map(|r| r.view()).collect();
        Ok(ndarray::stack(ndarray::Axis(0), &views)?.into_dyn())
    };
    let npy = [
        (
            "heldout_u0",
            stacked(&heldout.u0)?,
            "held-out true initial states [cases, 128]",
        ),
        (
            "heldout_observed",
            stacked(&heldout.obs)?,
            "held-out observed states at step 16 [cases, 128]",
        ),
        (
            "u0_network_dp",
            stacked(&dp_u0)?,
            "initial states from the network trained through the solver",
        ),
        (
            "u0_network_supervised",
            stacked(&supervised_u0)?,
            "initial states from the supervised network",
        ),
        (
            "u0_per_instance",
            stacked(&per_instance_u0)?,
            "initial states after 50 gradient steps from zero",
        ),
        (
            "u0_warm_started",
            stacked(&warm_u0)?,
            "the solver-trained network's states refined by 5 gradient steps",
        ),
    ];
    args.write_npy(
        &npy.iter()
            .map(|(n, a, m)| (*n, a.view(), *m))
            .collect::<Vec<_>>(),
    )?;

    common::print_json_line(&serde_json::json!({
        "example": "nn_control_burgers",
        "training_cases": train_count,
        "heldout_cases": heldout.len(),
        "training_steps": budget.steps,
        "batch": budget.batch,
        "parameters": dp.params.count(),
        "heldout_physics_loss_dp": loss_dp,
        "heldout_physics_loss_supervised": loss_supervised,
        "heldout_physics_loss_zero": loss_zero,
        "heldout_physics_loss_per_instance": loss_per_instance,
        "heldout_physics_loss_warm_started": loss_warm,
        "heldout_physics_loss_warm_started_supervised": loss_warm_supervised,
        "heldout_u0_error_dp": u0_err_dp,
        "heldout_u0_error_supervised": u0_err_supervised,
        "heldout_u0_error_zero": u0_err_zero,
        "heldout_u0_error_per_instance": u0_err_per_instance,
        "heldout_u0_error_warm_started": u0_err_warm,
        "final_training_loss_dp": dp.final_training_loss,
        "final_training_loss_supervised": supervised.final_training_loss,
        "training_seconds_dp": dp.seconds,
        "training_seconds_supervised": supervised.seconds,
        "seconds_per_case_network": seconds_per_case_network,
        "seconds_per_case_per_instance": seconds_per_case_per_instance,
        "seconds_per_case_warm_started": seconds_per_case_warm_started,
        "refinement": descents,
    }));
    Ok(())
}
