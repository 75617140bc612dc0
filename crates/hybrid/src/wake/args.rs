//! The command line of a wake study (clap): every flag in `--help`, the
//! values parsed into typed [`Options`] with typed errors
//! ([`HybridError::Argument`], [`HybridError::ReOutOfRange`],
//! [`LearnError::EmptySplit`], [`LearnError::UnknownVariant`]). A scene
//! gives its defaults ([`Options`]) and its [`Channel`].

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use diffphys_flow::{Advection, Splitting};
use diffphys_learn::study::Variant;
use diffphys_learn::{LearnError, Split};
use diffphys_nn::Arithmetic;
use std::fmt::Display;

use super::{Body, Channel, ReferenceScheme, ADVECTIONS, ARITHMETICS, SPLITTINGS};
use crate::{HybridError, NetSize, Result};

/// A comma-separated list of Reynolds numbers, each checked against the
/// channel's range.
///
/// # Errors
/// [`HybridError::Argument`] for text that is not a number;
/// [`HybridError::ReOutOfRange`]; [`LearnError::EmptySplit`] for an empty list.
pub fn parse_re_list(
    channel: &Channel,
    option: &str,
    text: &str,
    split: Split,
) -> Result<Vec<f64>> {
    let list = entries(text)
        .map(|s| {
            s.parse::<f64>().map_err(|_| HybridError::Argument {
                option: option.into(),
                message: format!("not a number: {s:?}"),
            })
        })
        .map(|r| r.and_then(|re| channel.checked_re(re)))
        .collect::<Result<Vec<_>>>()?;
    if list.is_empty() {
        return Err(LearnError::EmptySplit {
            split,
            context: format!("{option} lists no Reynolds number"),
        }
        .into());
    }
    Ok(list)
}

/// The non-empty, trimmed entries of a comma-separated list.
fn entries(text: &str) -> impl Iterator<Item = &str> {
    text.split(',').map(str::trim).filter(|s| !s.is_empty())
}

/// A comma-separated list, each entry parsed by `parse` (`Err`: why the
/// entry is not `what`).
///
/// # Errors
/// [`HybridError::Argument`] for an entry `parse` refuses, or no entry.
pub fn checked_list<T>(
    option: &str,
    what: &str,
    text: &str,
    parse: impl Fn(&str) -> std::result::Result<T, String>,
) -> Result<Vec<T>> {
    let argument = |message: String| HybridError::Argument {
        option: option.into(),
        message,
    };
    let list = entries(text)
        .map(|s| parse(s).map_err(argument))
        .collect::<Result<Vec<T>>>()?;
    if list.is_empty() {
        return Err(argument(format!("lists no {what}")));
    }
    Ok(list)
}

/// The value named `name` in a table of names; an argument error for
/// `option` listing the names otherwise.
pub fn parse_named<T: Copy>(table: &[(&'static str, T)], option: &str, name: &str) -> Result<T> {
    table
        .iter()
        .find(|(n, _)| *n == name.trim())
        .map(|(_, v)| *v)
        .ok_or_else(|| HybridError::Argument {
            option: option.into(),
            message: format!(
                "{name:?} is not one of {}",
                table.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ")
            ),
        })
}

/// A wake study's typed options (the seeds, `--small`, `--out`,
/// `--iterations` and `--npy` stay in the command line's [`TrainArgs`]); a
/// scene gives their defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// The variants to train (`src` always runs).
    pub variants: Vec<Variant>,
    /// Training Reynolds numbers.
    pub train_re: Vec<f64>,
    /// Validation Reynolds numbers: by default inside the training range
    /// (141, 566) and outside it on both sides (85, 1900), as the held-out
    /// split is.
    pub validation_re: Vec<f64>,
    /// Held-out Reynolds numbers.
    pub held_out_re: Vec<f64>,
    /// Learning rates to choose from on validation.
    pub learning_rates: Vec<f64>,
    /// The corrector sizes of the capacity sweep besides the main size
    /// (empty: no sweep).
    pub capacity: Vec<NetSize>,
    /// Run the speed study.
    pub speed: bool,
    /// Trainings (and held-out evaluations) run at once, each on its own
    /// thread (default: the available cores).
    pub threads: usize,
    /// The coarse solver's advection (`--coarse-advection`).
    pub coarse_advection: Advection,
    /// The coarse solver's splitting (`--coarse-splitting`).
    pub coarse_splitting: Splitting,
    /// How each resolution sees the cylinder (`--body cylinder|staircase|inscribed`).
    pub body: Body,
    /// The reference's scheme (`--reference-scheme second-order|coarse`).
    pub reference: ReferenceScheme,
    /// How much finer than the coarse grid the reference is, in space and
    /// time (`--reference-factor`; a power of two, at least 2).
    pub reference_factor: usize,
    /// The corrector's convolution arithmetic (`--network-arithmetic f32|f64`).
    pub arithmetic: Arithmetic,
}

impl Options {
    /// The unrolls of the SOL variants, in order.
    pub fn unrolls(&self) -> Vec<usize> {
        self.variants
            .iter()
            .filter_map(|v| match v {
                Variant::Sol(k) => Some(*k),
                _ => None,
            })
            .collect()
    }

    /// Whether `re` lies inside the training range.
    pub fn inside(&self, re: f64) -> bool {
        let lo = self.train_re.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = self
            .train_re
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        (lo..=hi).contains(&re)
    }
}
/// A hybrid wake-flow solver: a coarse flow solver with a corrector
/// trained through it against a finer reference, tested at Reynolds
/// numbers it never saw (docs/11-wake-flow.md). List defaults are the
/// scene's; a run prints them as it starts.
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
    /// CI size: the scene's small grid, short trajectories, small budgets.
    #[arg(long)]
    pub small: bool,
    /// Folder for charts, the reference cache and saved models [default: out/wake_flow].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Held-out Reynolds numbers, within the scene's range [default: the scene's].
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
    /// How much finer the reference is than the coarse grid, in space and time: 2, 4, 8 or 16 [default: the scene's].
    #[arg(long, value_name = "N")]
    pub reference_factor: Option<usize>,
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
    /// Training Reynolds numbers [default: the scene's].
    #[arg(long, value_name = "LIST")]
    pub train_re: Option<String>,
    /// Validation Reynolds numbers [default: the scene's].
    #[arg(long, value_name = "LIST")]
    pub validation_re: Option<String>,
    /// Variants to train (src always runs) [default: the scene's].
    #[arg(long, value_name = "LIST")]
    pub variants: Option<String>,
    /// Learning rates to choose from on validation [default: the scene's].
    #[arg(long, value_name = "LIST")]
    pub lrs: Option<String>,
    /// Adam steps of the scene's corrector evaluations per step each [default:
    /// the scene's budget].
    #[arg(long, value_name = "N")]
    pub iterations: Option<usize>,
    /// Corrector sizes of the capacity sweep besides the main size [default: the scene's].
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

    /// The scene's options: `defaults` (the scene's, full or small as
    /// `--small` says) with these flags applied, Reynolds numbers checked
    /// against `channel`.
    ///
    /// # Errors
    /// As [`Options::from_args`].
    pub fn options(&self, channel: &Channel, defaults: Options) -> Result<Options> {
        let mut o = defaults;
        if let Some(list) = &self.held_out_re {
            o.held_out_re = parse_re_list(channel, "--held-out-re", list, Split::HeldOut)?;
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
        if let Some(f) = self.reference_factor {
            if !((2..=16).contains(&f) && f.is_power_of_two()) {
                return Err(HybridError::Argument {
                    option: "--reference-factor".into(),
                    message: format!("not 2, 4, 8 or 16: {f}"),
                });
            }
            o.reference_factor = f;
        }
        if let Some(n) = self.threads {
            if n == 0 {
                return Err(HybridError::Argument {
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
    /// The typed options of a study's command line: the scene's `defaults`
    /// with the flags applied; `main_size` is trained anyway, so the capacity
    /// sweep leaves it out.
    ///
    /// # Errors
    /// [`LearnError::UnknownVariant`]; [`LearnError::ZeroUnroll`]
    /// for `sol0`; [`HybridError::ReOutOfRange`];
    /// [`LearnError::EmptySplit`] for an empty Re list;
    /// [`HybridError::Argument`] for an unknown name, an unparsable number, a
    /// learning rate that is not positive or a bad size.
    pub fn from_args(
        args: &TrainArgs,
        channel: &Channel,
        defaults: Options,
        main_size: NetSize,
    ) -> Result<Self> {
        let mut o = args.scene.options(channel, defaults)?;
        let re_list = |option, list, split| parse_re_list(channel, option, list, split);
        if let Some(list) = &args.train_re {
            o.train_re = re_list("--train-re", list, Split::Train)?;
        }
        if let Some(list) = &args.validation_re {
            o.validation_re = re_list("--validation-re", list, Split::Validation)?;
        }
        if let Some(list) = &args.variants {
            let mut variants = vec![Variant::Src];
            // each entry's own typed error (an unknown variant, an unroll of 0)
            for name in entries(list) {
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
                        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
                        _ => Err(format!("not a positive learning rate: {s:?}")),
                    }
                })?;
        }
        if args.no_capacity {
            o.capacity = Vec::new();
        }
        if let Some(list) = &args.capacity_sizes {
            o.capacity = checked_list("--capacity-sizes", "a network size", list, |s| {
                s.parse::<NetSize>().map_err(|e| e.to_string())
            })?
            .into_iter()
            .filter(|s| *s != main_size)
            .collect();
        }
        o.speed = !args.no_speed;
        Ok(o)
    }
}

/// The training and data seeds of a study's command line: `(data, train)`.
///
/// # Errors
/// [`HybridError::Argument`] for a list that is not seeds, or an empty one.
pub fn seeds(args: &TrainArgs) -> Result<(Vec<u64>, Vec<u64>)> {
    let list = |option: &str, text: &str| {
        checked_list(option, "a seed", text, |s| {
            s.parse::<u64>().map_err(|_| format!("not a seed: {s:?}"))
        })
    };
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

/// `command` (a study's [`Cli`]) with the help of each list flag ending in
/// the scene's defaults, full and `--small` (`[default: …]`), here and in
/// the subcommands that take it.
pub fn with_defaults(command: clap::Command, full: &Options, small: &Options) -> clap::Command {
    fn list<T: Display>(v: &[T]) -> String {
        v.iter().map(T::to_string).collect::<Vec<_>>().join(",")
    }
    let both = |f: String, s: String| {
        if f == s {
            format!("[default: {f}]")
        } else {
            format!("[default: {f}; --small: {s}]")
        }
    };
    let names = |o: &Options| list(&o.variants.iter().map(|v| v.name()).collect::<Vec<_>>());
    let sizes = |o: &Options| list(&o.capacity.iter().map(|s| s.label()).collect::<Vec<_>>());
    let defaults = [
        (
            "held_out_re",
            both(list(&full.held_out_re), list(&small.held_out_re)),
        ),
        (
            "train_re",
            both(list(&full.train_re), list(&small.train_re)),
        ),
        (
            "validation_re",
            both(list(&full.validation_re), list(&small.validation_re)),
        ),
        ("variants", both(names(full), names(small))),
        (
            "lrs",
            both(list(&full.learning_rates), list(&small.learning_rates)),
        ),
        ("capacity_sizes", both(sizes(full), sizes(small))),
    ];
    let annotate = |mut c: clap::Command| {
        for (id, default) in &defaults {
            if c.get_arguments().any(|a| a.get_id() == *id) {
                c = c.mut_arg(*id, |a| {
                    let help = a.get_help().map(|h| h.to_string()).unwrap_or_default();
                    let help = help.replace("[default: the scene's]", "");
                    a.help(format!("{} {default}", help.trim_end()))
                });
            }
        }
        c
    };
    let command = annotate(command);
    let subcommands: Vec<String> = command
        .get_subcommands()
        .map(|s| s.get_name().to_owned())
        .collect();
    subcommands
        .iter()
        .fold(command, |c, name| c.mut_subcommand(name, annotate))
}
