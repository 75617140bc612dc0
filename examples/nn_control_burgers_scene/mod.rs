//! The scene of `nn_control_burgers` beside the Burgers solver: its cases,
//! the two trainings' record, the held-out analysis (network predictions,
//! per-instance descent, refinement) and the charts.

use std::path::{Path, PathBuf};
use std::time::Instant;

use diffphys::nn::{Layer, Params, UNet};
use diffphys::prelude::*;
use diffphys::report::chart::{line_chart_svg, LineChart, Series};
use ndarray::Array1;
use rand::rngs::StdRng;
use serde_json::{json, Value};

use super::burgers_scene::{
    batch_of, curve, mse, random_initial_state, sample_of, BoxError, Burgers, DESCENT_RATE, N,
};

/// Per-instance optimisation: the gradient-descent steps of `burgers_inverse`,
/// and the steps that refine a network's prediction.
pub const PER_INSTANCE_STEPS: usize = 50;
pub const REFINE_STEPS: usize = 5;

/// Initial states and their observations.
pub struct Cases {
    pub u0: Vec<Array1<f64>>,
    pub obs: Vec<Array1<f64>>,
}

impl Cases {
    pub fn draw(scene: &Burgers, count: usize, rng: &mut StdRng) -> Result<Self, BoxError> {
        let u0: Vec<_> = (0..count)
            .map(|_| random_initial_state(&scene.grid, rng))
            .collect();
        let obs = u0
            .iter()
            .map(|u| scene.observe_plain(u))
            .collect::<Result<_, _>>()?;
        Ok(Cases { u0, obs })
    }

    pub fn len(&self) -> usize {
        self.u0.len()
    }
}

/// What a network is trained on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Training {
    /// Through the solver: `mean((P(net(obs)) − obs)²)`.
    Physics,
    /// On the known initial states: `mean((net(obs) − u₀)²)`.
    Supervised,
}

impl Training {
    pub fn label(self) -> &'static str {
        match self {
            Training::Physics => "differentiable physics",
            Training::Supervised => "supervised",
        }
    }

    /// The key of its figures: `dp`, `supervised`.
    pub fn key(self) -> &'static str {
        match self {
            Training::Physics => "dp",
            Training::Supervised => "supervised",
        }
    }
}

impl std::fmt::Display for Training {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.label())
    }
}

/// A trained network and its record.
pub struct Run {
    pub training: Training,
    pub data_seed: u64,
    pub train_seed: u64,
    pub net: UNet,
    /// The parameters of the best validation score by the training's own
    /// objective.
    pub params: Params<f64>,
    /// That score, and the step it was reached at.
    pub validation: f64,
    pub kept_step: usize,
    /// Validation physics loss and initial-state error against the step.
    pub validation_physics: Vec<(usize, f64)>,
    pub validation_u0_error: Vec<(usize, f64)>,
    pub final_training_loss: f64,
    pub seconds: f64,
}

/// The network's initial states for a `[batch, 1, N]` batch of observations.
pub fn predict(
    net: &UNet,
    params: &Params<f64>,
    obs: &ArrayD<f64>,
) -> Result<ArrayD<f64>, BoxError> {
    let tape = Tape::new();
    let p = params.bind(&tape);
    let y = net.forward(&p, tape.constant(obs.clone()))?;
    Ok(y.to_array())
}

/// Physics loss and initial-state error of predicted initial states.
pub fn score(scene: &Burgers, cases: &Cases, u0: &[Array1<f64>]) -> Result<(f64, f64), BoxError> {
    let mut physics = 0.0;
    let mut u0_error = 0.0;
    for ((u, truth), obs) in u0.iter().zip(&cases.u0).zip(&cases.obs) {
        physics += mse(&scene.observe_plain(u)?, obs);
        u0_error += mse(u, truth);
    }
    let n = cases.len() as f64;
    Ok((physics / n, u0_error / n))
}

pub fn network_predictions(
    net: &UNet,
    params: &Params<f64>,
    cases: &Cases,
) -> Result<Vec<Array1<f64>>, BoxError> {
    let obs = batch_of(&cases.obs.iter().collect::<Vec<_>>());
    let pred = predict(net, params, &obs)?;
    Ok((0..cases.len()).map(|b| sample_of(&pred, b)).collect())
}

/// Per-instance gradient descent from each of `starts`; returns the results and
/// the seconds per case.
pub fn descend_all(
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
pub struct Descent {
    pub losses: Vec<f64>,
    pub best: f64,
    pub gradient_norm: f64,
    pub cases_worse: usize,
}

pub fn trace_descent(
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

/// What the held-out split says of one trained network (read once).
pub struct HeldOutNetwork {
    pub predictions: Vec<Array1<f64>>,
    pub physics: f64,
    pub u0_error: f64,
    /// After [`REFINE_STEPS`] gradient steps from the predictions.
    pub refined: Vec<Array1<f64>>,
    pub refined_physics: f64,
    pub refined_u0_error: f64,
    pub seconds_network: f64,
    pub seconds_refined: f64,
    pub descent: Descent,
}

pub fn held_out_network(
    scene: &Burgers,
    run: &Run,
    cases: &Cases,
) -> Result<HeldOutNetwork, BoxError> {
    let start = Instant::now();
    let predictions = network_predictions(&run.net, &run.params, cases)?;
    let seconds_network = start.elapsed().as_secs_f64() / cases.len() as f64;
    let (refined, seconds_refine) = descend_all(scene, cases, &predictions, REFINE_STEPS)?;
    let (physics, u0_error) = score(scene, cases, &predictions)?;
    let (refined_physics, refined_u0_error) = score(scene, cases, &refined)?;
    let descent = trace_descent(scene, cases, &predictions, REFINE_STEPS)?;
    Ok(HeldOutNetwork {
        predictions,
        physics,
        u0_error,
        refined,
        refined_physics,
        refined_u0_error,
        seconds_network,
        seconds_refined: seconds_network + seconds_refine,
        descent,
    })
}

/// The baselines on the held-out split: the zero initial state and
/// per-instance optimisation from it.
pub struct Baselines {
    /// The split's true initial states and observations (for the charts and
    /// `--npy`).
    pub truth: Vec<Array1<f64>>,
    pub observed: Vec<Array1<f64>>,
    pub zero: (f64, f64),
    pub per_instance: (f64, f64),
    pub per_instance_u0: Vec<Array1<f64>>,
    pub seconds_per_instance: f64,
    pub descent: Descent,
}

pub fn baselines(scene: &Burgers, cases: &Cases) -> Result<Baselines, BoxError> {
    let zeros = vec![Array1::zeros(N); cases.len()];
    let (per_instance_u0, seconds_per_instance) =
        descend_all(scene, cases, &zeros, PER_INSTANCE_STEPS)?;
    Ok(Baselines {
        truth: cases.u0.clone(),
        observed: cases.obs.clone(),
        zero: score(scene, cases, &zeros)?,
        per_instance: score(scene, cases, &per_instance_u0)?,
        per_instance_u0,
        seconds_per_instance,
        descent: trace_descent(scene, cases, &zeros, REFINE_STEPS)?,
    })
}

/// A horizontal line across `steps` for a level in a chart.
pub fn level(label: &str, steps: usize, value: f64) -> Series {
    Series::new(label, vec![(0.0, value), (steps as f64, value)])
}

/// The validation curves of `runs` (one data seed), and held-out case 0 of
/// its first training seed.
pub fn write_charts(
    out: &Path,
    scene: &Burgers,
    runs: &[&Run],
    steps: usize,
    untrained_levels: &[(&str, f64)],
    shown: [(&str, &Array1<f64>); 4],
) -> Result<Vec<PathBuf>, BoxError> {
    let mut files = Vec::new();
    let label = |r: &Run| format!("{}, seed {}", r.training.label(), r.train_seed);
    for (name, what, pick) in [
        (
            "validation_physics_loss.svg",
            "physics loss mean((P(net(obs)) - obs)^2)",
            (|r: &Run| &r.validation_physics) as fn(&Run) -> &Vec<(usize, f64)>,
        ),
        (
            "validation_u0_error.svg",
            "initial-state error mean((net(obs) - u0)^2)",
            |r: &Run| &r.validation_u0_error,
        ),
    ] {
        let mut series: Vec<Series> = runs.iter().map(|r| curve(&label(r), pick(r))).collect();
        if name.contains("physics") {
            series.extend(untrained_levels.iter().map(|(l, v)| level(l, steps, *v)));
        }
        let path = out.join(name);
        line_chart_svg(
            &path,
            &LineChart {
                title: &format!("Validation {what} during training"),
                x_label: "training step",
                y_label: what,
                log_x: false,
                log_y: true,
                series: &series,
            },
        )?;
        files.push(path);
    }
    let x = scene.grid.centers();
    let along_x = |label: String, v: &Array1<f64>| {
        Series::new(label, x.iter().copied().zip(v.iter().copied()).collect())
    };
    let initial: Vec<Series> = shown
        .iter()
        .map(|(label, u)| along_x(label.to_string(), u))
        .collect();
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
    for (name, title, series) in [
        (
            "heldout_case_initial.svg",
            "Held-out case 0: initial state u(t=0)",
            initial,
        ),
        (
            "heldout_case_observed.svg",
            "Held-out case 0: state at t = 0.5 from each initial state",
            observed,
        ),
    ] {
        let path = out.join(name);
        line_chart_svg(
            &path,
            &LineChart {
                title,
                x_label: "x",
                y_label: "u",
                log_x: false,
                log_y: false,
                series: &series,
            },
        )?;
        files.push(path);
    }
    Ok(files)
}

pub fn descent_json(d: &Descent) -> Value {
    json!({
        "losses": d.losses,
        "best_iterate": d.best,
        "gradient_norm": d.gradient_norm,
        "cases_worse": d.cases_worse,
    })
}
