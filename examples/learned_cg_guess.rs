//! A learned initial guess for conjugate gradient: the iterations of CG as a
//! virtual time through which a network is trained (`diffphys_learn::guess`).
//!
//! Physics: `A x = b` with `A = −∇²` on `n × n` cells of `[0, 1]²`, zero
//! Dirichlet walls (n = 64; 32 with `--small`); `b = ∇·u` (staggered) of a
//! random band-limited velocity, each component `Σ c_{kl} φ(πkx) ψ(πly)` over
//! `k, l = 1..n/4`, `φ, ψ ∈ {cos, sin}`, `c ~ U[−1, 1]`.
//!
//! Network: a U-Net without nonlinearity (`b ↦ A⁻¹b` is linear), widths 8, 16,
//! 16, 32, 32, 3 × 3 kernels, zero padding; `x₀ = s·c·net(b/s)` with `s = rms(b)`
//! and `c` the mean `rms(x*)/rms(b)` of the training split's calibration batch.
//!
//! Budget: 300 Adam steps (2e-3, cosine to 1%) of 8 fresh right-hand sides from
//! the training stream, the same for every loss: supervised (`‖x₀ − x*‖²/‖x*‖²`)
//! and through `k` recorded CG iterations (`‖r_k‖²/‖b‖²`, k = 2, 5, 10). Early
//! stopping and `k` are chosen on the validation split (mean CG iterations to
//! 1e-1 and 1e-2); each trained model is evaluated once on the held-out split.
//! `--data-seed`/`--train-seeds` as every learning scene; default 3 × 3.
//! Tutorial: docs/06-training-through-the-solver.md (scene 3). Run:
//! `cargo run --release --example learned_cg_guess` (`-- --small` for CI).

mod common;
mod learned_cg_guess_scene;

use std::collections::BTreeMap;
use std::time::Instant;

use diffphys::learn::guess::{
    guesses, iterations_to, GuessLoss, GuessProblem, GuessTrainer, InitialGuess, TrainedGuess,
};
use diffphys::learn::{
    select_best, Candidate, DataSeed, LearnError, LrSchedule, Report, Split, Splits, TrainSeed,
    Trained,
};
use diffphys::nn::{Activation, Bound, Layer, Padding, Params, UNet, UNetConfig};
use diffphys::ops::stencil::Laplacian2;
use diffphys::prelude::{ArrayD, Boundary, Grid2, Var};
use diffphys::report::chart::{line_chart_svg, LineChart, Series};
use diffphys::report::progress_bar;
use ndarray::IxDyn;
use rand::rngs::StdRng;
use serde_json::json;

use learned_cg_guess_scene::{rms, RhsDistribution};

type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// The tolerances of the evaluation, loosest first.
const TOLERANCES: [(f64, &str); 4] = [
    (1e-1, "1e-1"),
    (1e-2, "1e-2"),
    (1e-3, "1e-3"),
    (1e-6, "1e-6"),
];
/// The unrolled CG iterations offered to validation.
const UNROLLS: [usize; 3] = [2, 5, 10];

/// The network and its output scaling, `x₀ = s·c·net(b/s)`.
struct Guess {
    net: UNet,
    output_scale: f64,
}

impl InitialGuess for Guess {
    fn guess<'t>(
        &self,
        p: &Bound<'t, f64>,
        b: Var<'t, f64>,
    ) -> diffphys::tape::Result<Var<'t, f64>> {
        let value = b.value();
        let scales: Vec<f64> = value.outer_iter().map(|s| rms(&s.to_owned())).collect();
        let mut shape = vec![1; value.ndim()];
        shape[0] = scales.len();
        let per = |f: &dyn Fn(f64) -> f64| {
            ArrayD::from_shape_vec(IxDyn(&shape), scales.iter().map(|&s| f(s)).collect())
        };
        let tape = b.tape();
        let input = b.mul(tape.constant(per(&|s| 1.0 / s).expect("one per sample")))?;
        let out = tape.constant(per(&|s| s * self.output_scale).expect("one per sample"));
        self.net.forward(p, input)?.mul(out)
    }
}

fn network(
    widths: &[usize],
    seed: TrainSeed,
    output_scale: f64,
) -> Result<(Guess, Params<f64>), BoxError> {
    let config = UNetConfig {
        dims: 2,
        c_in: 1,
        c_out: 1,
        widths: widths.to_vec(),
        kernel: 3,
        padding: Padding::Zero,
        activation: Activation::Identity,
    };
    let mut params = Params::new();
    let net = UNet::new(&mut params, "guess", config, &mut seed.init_rng())?;
    Ok((Guess { net, output_scale }, params))
}

/// Mean CG iterations per tolerance over `problems` from the guesses of `params`.
fn iterations(
    lap: &Laplacian2,
    guess: &Guess,
    params: Option<&Params<f64>>,
    problems: &[GuessProblem],
) -> Result<Vec<f64>, LearnError> {
    let bs: Vec<&ArrayD<f64>> = problems.iter().map(|p| &p.b).collect();
    let x0s = guesses(guess, params, &bs)?;
    let mut mean = vec![0.0; TOLERANCES.len()];
    for (p, x0) in problems.iter().zip(&x0s) {
        for (m, &(tol, _)) in mean.iter_mut().zip(&TOLERANCES) {
            *m += iterations_to(lap, &p.b, x0, tol)? as f64 / problems.len() as f64;
        }
    }
    Ok(mean)
}

/// A learned initial guess for conjugate gradient, trained through the CG iterations.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
    #[command(flatten)]
    seeds: common::Seeds,
    /// Adam steps (40 with --small).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 300,
        default_value_if("small", "true", "40")
    )]
    iterations: usize,
}

fn main() -> Result<(), BoxError> {
    let run_start = Instant::now();
    let Cli {
        common: args,
        seeds,
        iterations: steps,
    } = common::parse_args("learned_cg_guess")?;
    let n = args.pick(64, 32);
    let widths = args.pick(vec![8, 16, 16, 32, 32], vec![4, 8, 8, 16]);
    let trainer = GuessTrainer {
        steps,
        batch: args.pick(8, 4),
        learning_rate: 2e-3,
        schedule: LrSchedule::Cosine {
            final_fraction: 0.01,
        },
        validate_every: args.pick(15, 10),
        validation_tolerances: vec![1e-1, 1e-2],
    };
    let [validation_n, held_out_n] = args.pick([16, 64], [8, 16]);
    let lap = Laplacian2::negative(Grid2::square(
        n,
        n,
        1.0 / n as f64,
        Boundary::ZeroDirichlet,
    )?);
    let dist = RhsDistribution::new(n, n / 4);
    let mut losses = vec![GuessLoss::Supervised];
    losses.extend(UNROLLS.map(|iterations| GuessLoss::ThroughSolver { iterations }));

    let mut reports: BTreeMap<&str, Report> = BTreeMap::new();
    let mut selected_k = serde_json::Map::new();
    for &ds in &seeds.data {
        // The training split is the calibration batch (the first batch of the
        // training stream, which every training then draws afresh).
        let splits = Splits::generate(
            DataSeed(ds),
            [trainer.batch, validation_n, held_out_n],
            |_, count, rng| {
                (0..count)
                    .map(|_| dist.draw(&lap, rng))
                    .collect::<Result<Vec<_>, _>>()
            },
        )?;
        let scale = splits
            .train
            .iter()
            .map(|p| rms(&p.x_star) / rms(&p.b))
            .sum::<f64>()
            / splits.train.len() as f64;
        let (guess, _) = network(&widths, TrainSeed(0), scale)?;
        println!("data seed {ds}: n = {n}, U-Net widths {widths:?} (receptive field {}), {} steps of batch {}", guess.net.receptive_field(), trainer.steps, trainer.batch);
        let mut groups: Vec<(GuessLoss, Vec<Trained<TrainedGuess>>)> = Vec::new();
        for &loss in &losses {
            let mut group = Vec::new();
            for &ts in &seeds.train {
                let (_, params) = network(&widths, TrainSeed(ts), scale)?;
                let bar = progress_bar(
                    trainer.steps,
                    &format!("data {ds} {} seed {ts}", loss.name()),
                );
                let start = Instant::now();
                let mut draw = |rng: &mut StdRng| dist.draw(&lap, rng);
                let t = trainer.train(
                    &lap,
                    &guess,
                    params,
                    loss,
                    &mut draw,
                    DataSeed(ds).rng(Split::Train),
                    &splits.validation,
                    &|| bar.inc(1),
                )?;
                bar.finish_and_clear();
                println!("  {:>14}, train seed {ts}: {:.1} s, validation {:.2} iterations (kept step {})", loss.name(), start.elapsed().as_secs_f64(), t.model.validation, t.model.best_step);
                group.push(t);
            }
            groups.push((loss, group));
        }
        // Selection on validation only: `k` by the mean validation score over
        // the training seeds; the supervised guess has nothing to choose.
        let candidate = |(l, g): (GuessLoss, Vec<Trained<TrainedGuess>>)| {
            let v = g.iter().map(|t| t.model.validation).sum::<f64>() / g.len() as f64;
            Candidate::new(l.name(), Trained::new(g), v)
        };
        let through = groups.split_off(1);
        let selections = [
            select_best(through.into_iter().map(candidate).collect())?,
            select_best(groups.into_iter().map(candidate).collect())?,
        ];
        let chosen = selections[0]
            .chosen_label()
            .trim_start_matches("through_cg_")
            .parse::<usize>()?;
        println!("  selected by validation: k = {chosen}");
        selected_k.insert(ds.to_string(), json!(chosen));
        let zero = splits
            .held_out()
            .evaluate_baseline(|d| iterations(&lap, &guess, None, d))?;
        let mut add = |name: &str, ts: Option<u64>, per_tol: &[f64]| {
            for (&(_, key), &v) in TOLERANCES.iter().zip(per_tol) {
                reports.entry(key).or_default().add(name, ds, ts, v);
            }
        };
        add("zero", None, &zero);
        for selection in selections {
            for model in selection.models {
                let e = splits.held_out().evaluate(model, |group, d| {
                    group
                        .iter()
                        .map(|t| iterations(&lap, &guess, Some(&t.model.params), d))
                        .collect::<Result<Vec<_>, _>>()
                })?;
                for (per_tol, &ts) in e.result.iter().zip(&seeds.train) {
                    add(&e.label, Some(ts), per_tol);
                    if e.label.starts_with("through_cg_") && e.chosen {
                        add("learned_selected", Some(ts), per_tol);
                    }
                }
            }
        }
    }

    println!("\nheld-out mean CG iterations ({held_out_n} right-hand sides per data seed; data seeds {:?} × train seeds {:?}):", seeds.data, seeds.train);
    for (&key, report) in &reports {
        println!(
            "to relative residual {key}:\n{}",
            report.table(Some("zero"))
        );
    }
    let mean = |key: &str, m: &str| reports[key].summary(m).map_or(f64::NAN, |s| s.mean);
    let ratio = |key: &str| mean(key, "learned_selected") / mean(key, "zero");
    let per_seed = |key: &str| -> serde_json::Map<String, serde_json::Value> {
        let zero = reports[key].per_data_seed("zero");
        reports[key]
            .per_data_seed("learned_selected")
            .iter()
            .zip(zero)
            .map(|(&(d, l), (_, z))| (d.to_string(), json!(l / z)))
            .collect()
    };
    let series: Vec<Series> = reports["1e-1"]
        .methods()
        .map(|m| {
            Series::new(
                m,
                TOLERANCES
                    .iter()
                    .map(|&(tol, key)| (tol, mean(key, m)))
                    .collect(),
            )
        })
        .collect();
    line_chart_svg(
        &args.out.join("iterations.svg"),
        &LineChart {
            title: "learned_cg_guess: mean CG iterations to a relative residual (held out)",
            x_label: "relative residual ‖b − A x‖ / ‖b‖",
            y_label: "CG iterations",
            log_x: true,
            log_y: false,
            series: &series,
        },
    )?;
    println!("chart written to {}", args.out.display());
    let floors = json!({
        "learned_at_most_0.4x_zero_at_1e-1": ratio("1e-1") <= 0.4,
        "learned_at_most_0.8x_zero_at_1e-2": ratio("1e-2") <= 0.8,
    });
    println!("learned (validation-selected k) / zero: 1e-1 {:.3}, 1e-2 {:.3}, 1e-3 {:.3}, 1e-6 {:.3}; floors {floors}", ratio("1e-1"), ratio("1e-2"), ratio("1e-3"), ratio("1e-6"));
    common::print_json_line(&json!({
        "example": "learned_cg_guess",
        "small": args.small,
        "n": n,
        "data_seeds": seeds.data,
        "train_seeds": seeds.train,
        "training_steps": trainer.steps,
        "batch": trainer.batch,
        "held_out_per_data_seed": held_out_n,
        "iterations": reports.iter().map(|(k, r)| (k.to_string(), r.to_json())).collect::<serde_json::Map<_, _>>(),
        "learned_over_zero": TOLERANCES.iter().map(|&(_, k)| (k.to_string(), json!(ratio(k)))).collect::<serde_json::Map<_, _>>(),
        "learned_over_zero_per_data_seed": TOLERANCES.iter().map(|&(_, k)| (k.to_string(), json!(per_seed(k)))).collect::<serde_json::Map<_, _>>(),
        "selected_k": selected_k,
        "selected_by": "validation",
        "floors": floors,
        "peak_rss_bytes": common::peak_rss_bytes(),
        "seconds": run_start.elapsed().as_secs_f64(),
    }));
    Ok(())
}
