//! The command line of `wake_flow` (clap): every flag with its default in
//! `--help`, the values parsed into typed [`Options`] with the scene's typed
//! errors.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use super::{
    checked_list, parse_named, parse_re_list, Body, NetSize, Options, ReferenceScheme, Result,
    Variant, WakeError, ADVECTIONS, ARITHMETICS, MAIN_SIZE, SPLITTINGS,
};
use diffphys::learn::Split;

/// The hybrid wake-flow solver: a coarse flow solver with a corrector
/// trained through it against a 4x finer reference, tested at Reynolds
/// numbers it never saw (docs/11-wake-flow.md).
#[derive(Debug, Parser)]
#[command(name = "wake_flow", version, args_conflicts_with_subcommands = true)]
pub struct Cli {
    /// `evaluate`: a saved corrector at any Re; `convergence`: the reference
    /// against one level finer; without one, train the study.
    #[command(subcommand)]
    pub command: Option<Command>,
    /// The study's options.
    #[command(flatten)]
    pub train: TrainArgs,
}

/// What `wake_flow` does besides training.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Roll a saved corrector out at each Reynolds number of --held-out-re
    /// (reference generated or read from OUT/reference), without training.
    Evaluate(EvaluateArgs),
    /// The reference against the same scheme one level finer, restricted to
    /// the coarse grid, at every train, validation and held-out Re; each
    /// level's drag, lift periods and Strouhal number.
    Convergence(ConvergenceArgs),
}

/// `wake_flow convergence`.
#[derive(Debug, Clone, Args)]
pub struct ConvergenceArgs {
    /// The data seed whose streams draw each split's start state.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub data_seed: u64,
    /// The scene.
    #[command(flatten)]
    pub scene: SceneArgs,
}

/// What the scene is: the same for training and evaluation.
#[derive(Debug, Clone, Args)]
pub struct SceneArgs {
    /// CI size: 16 x 32 coarse cells, short trajectories, small budgets.
    #[arg(long)]
    pub small: bool,
    /// Folder for charts, the reference cache and saved models [default: out/wake_flow].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Held-out Reynolds numbers, in [50, 3200] [default: 71,283,1131,2263; --small: 283,2263].
    #[arg(long, value_name = "LIST")]
    pub held_out_re: Option<String>,
    /// The coarse solver's advection: semi-lagrangian or maccormack.
    #[arg(long, default_value = "semi-lagrangian", value_name = "NAME")]
    pub coarse_advection: String,
    /// The coarse solver's splitting: plain or incremental (second order; the state then carries the pressure).
    #[arg(long, default_value = "plain", value_name = "NAME")]
    pub coarse_splitting: String,
    /// How each resolution sees the cylinder: cylinder, staircase or inscribed.
    #[arg(long, default_value = "inscribed", value_name = "NAME")]
    pub body: String,
    /// The reference's scheme: second-order or coarse.
    #[arg(long, default_value = "second-order", value_name = "NAME")]
    pub reference_scheme: String,
    /// The corrector's convolution arithmetic: f32 or f64.
    #[arg(long, default_value = "f32", value_name = "NAME")]
    pub network_arithmetic: String,
    /// Trainings (and rollouts) run at once [default: the available cores].
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
}

/// The study: what is trained, on what, with which budget.
#[derive(Debug, Clone, Args)]
pub struct TrainArgs {
    /// The scene.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// The data seed (train, validation and held-out draws; each costs its own reference).
    #[arg(long, value_name = "N", conflicts_with = "data_seeds")]
    pub data_seed: Option<u64>,
    /// Several data seeds [default: 1].
    #[arg(long, value_name = "LIST")]
    pub data_seeds: Option<String>,
    /// Training seeds [default: 1,2,3; --small: 1].
    #[arg(long, value_name = "LIST")]
    pub train_seeds: Option<String>,
    /// Training Reynolds numbers [default: 100,200,400,800,1600; --small: 200,400,800].
    #[arg(long, value_name = "LIST")]
    pub train_re: Option<String>,
    /// Validation Reynolds numbers [default: 85,141,566,1900; --small: 566].
    #[arg(long, value_name = "LIST")]
    pub validation_re: Option<String>,
    /// Variants to train (src always runs) [default: src,non,noise,sol4,sol16].
    #[arg(long, value_name = "LIST")]
    pub variants: Option<String>,
    /// Learning rates to choose from on validation [default: 1e-3,3e-3; --small: 1e-3].
    #[arg(long, value_name = "LIST")]
    pub lrs: Option<String>,
    /// Adam steps of 4 corrector evaluations each: a budget of 4N evaluations
    /// [default: 12,000 steps, 48,000 evaluations; --small: 16 steps].
    #[arg(long, value_name = "N")]
    pub iterations: Option<usize>,
    /// Corrector sizes of the capacity sweep besides w16b2 [default: w8b1,w24b2].
    #[arg(long, value_name = "LIST", conflicts_with = "no_capacity")]
    pub capacity_sizes: Option<String>,
    /// No capacity sweep.
    #[arg(long)]
    pub no_capacity: bool,
    /// No speed study.
    #[arg(long)]
    pub no_speed: bool,
    /// Develop on validation only: train and select, save the models, run
    /// the speed study on the validation split; the held-out split is not read.
    #[arg(long)]
    pub validation_only: bool,
    /// Write the last states as .npy files under OUT/npy.
    #[arg(long)]
    pub npy: bool,
}

/// `wake_flow evaluate`.
#[derive(Debug, Clone, Args)]
pub struct EvaluateArgs {
    /// A saved model's folder (OUT/models/VARIANT_SIZE_dataD_seedS).
    #[arg(long, value_name = "DIR")]
    pub model: PathBuf,
    /// The data seed whose held-out stream draws the start state [default: the model's].
    #[arg(long, value_name = "N")]
    pub data_seed: Option<u64>,
    /// The scene (it must match the model's settings).
    #[command(flatten)]
    pub scene: SceneArgs,
}

impl SceneArgs {
    /// The output folder.
    pub fn out(&self) -> PathBuf {
        self.out
            .clone()
            .unwrap_or_else(|| PathBuf::from("out").join("wake_flow"))
    }

    /// The scene's options (the study's at their defaults).
    ///
    /// # Errors
    /// As [`Options::from_args`].
    pub fn options(&self) -> Result<Options> {
        let mut o = Options::defaults(self.small);
        if let Some(list) = &self.held_out_re {
            o.held_out_re = parse_re_list("--held-out-re", list, Split::HeldOut)?;
        }
        o.coarse_advection =
            parse_named(&ADVECTIONS, "--coarse-advection", &self.coarse_advection)?;
        o.coarse_splitting =
            parse_named(&SPLITTINGS, "--coarse-splitting", &self.coarse_splitting)?;
        o.body = parse_named(&Body::ALL, "--body", &self.body)?;
        o.reference = parse_named(
            &ReferenceScheme::ALL,
            "--reference-scheme",
            &self.reference_scheme,
        )?;
        o.arithmetic = parse_named(
            &ARITHMETICS,
            "--network-arithmetic",
            &self.network_arithmetic,
        )?;
        if let Some(n) = self.threads {
            if n == 0 {
                return Err(WakeError::Argument {
                    option: "--threads".into(),
                    message: "not a positive thread count: 0".into(),
                });
            }
            o.threads = n;
        }
        Ok(o)
    }
}

impl Options {
    /// The typed options of a study's command line.
    ///
    /// # Errors
    /// [`diffphys::learn::LearnError::UnknownVariant`]; [`diffphys::learn::LearnError::ZeroUnroll`]
    /// for `sol0`; [`WakeError::ReOutOfRange`];
    /// [`diffphys::learn::LearnError::EmptySplit`] for an empty Re list;
    /// [`WakeError::Argument`] for an unknown name, an unparsable number, a
    /// learning rate that is not positive or a bad size.
    pub fn from_args(args: &TrainArgs) -> Result<Self> {
        let mut o = args.scene.options()?;
        if let Some(list) = &args.train_re {
            o.train_re = parse_re_list("--train-re", list, Split::Train)?;
        }
        if let Some(list) = &args.validation_re {
            o.validation_re = parse_re_list("--validation-re", list, Split::Validation)?;
        }
        if let Some(list) = &args.variants {
            let mut variants = vec![Variant::Src];
            for name in list.split(',').filter(|s| !s.trim().is_empty()) {
                let variant: Variant = name.parse()?;
                if !variants.contains(&variant) {
                    variants.push(variant);
                }
            }
            o.variants = variants;
        }
        if let Some(list) = &args.lrs {
            o.learning_rates =
                checked_list("--lrs", "a positive learning rate", list, |s| {
                    match s.parse::<f64>() {
                        Ok(x) if x.is_finite() && x > 0.0 => Some(x),
                        _ => None,
                    }
                })?;
        }
        if args.no_capacity {
            o.capacity = Vec::new();
        }
        if let Some(list) = &args.capacity_sizes {
            o.capacity = list
                .split(',')
                .filter(|s| !s.trim().is_empty())
                .map(|s| {
                    s.trim()
                        .parse::<NetSize>()
                        .map_err(|e| WakeError::Argument {
                            option: "--capacity-sizes".into(),
                            message: e.to_string(),
                        })
                })
                .filter(|s| s.as_ref().map_or(true, |s| *s != MAIN_SIZE))
                .collect::<Result<_>>()?;
        }
        o.speed = !args.no_speed;
        Ok(o)
    }
}

/// The training and data seeds of a study's command line: `(data, train)`.
///
/// # Errors
/// [`WakeError::Argument`] for a list that is not seeds, or an empty one.
pub fn seeds(args: &TrainArgs) -> Result<(Vec<u64>, Vec<u64>)> {
    let list =
        |option: &str, text: &str| checked_list(option, "a seed", text, |s| s.parse::<u64>().ok());
    let data = match (&args.data_seeds, args.data_seed) {
        (Some(list_text), _) => list("--data-seeds", list_text)?,
        (None, Some(seed)) => vec![seed],
        // One data seed unless asked: each costs its own reference (~27,000
        // steps at 128 x 256); the spread comes from the training seeds.
        (None, None) => vec![1],
    };
    let train = match &args.train_seeds {
        Some(text) => list("--train-seeds", text)?,
        None if args.scene.small => vec![1],
        None => vec![1, 2, 3],
    };
    Ok((data, train))
}
