//! What a study's trainings, selections and held-out readings leave for its
//! report, over every data seed: the validation scores (overall and per
//! condition), each training's validation curve and wall time, the chosen
//! learning rates, the variant and size selected on validation, and how often
//! each data seed's held-out split was read (in this run and, through the
//! [`Ledger`], in every run of the output folder).
//!
//! A scene adds its own held-out figures beside these ([`crate::Figures`]);
//! [`Log::to_json`] gives the keys a study's JSON line carries.

use std::collections::BTreeMap;
use std::fmt::Display;
use std::path::Path;

use diffphys_report::chart::{LineChart, Series};
use serde_json::{json, Map, Value};

use super::{Ledger, TrainedRun, Variant};
use crate::report::chart_unless_empty;
use crate::{Report, Result, Summary};

/// A study's record of its trainings and selections: what it leaves for
/// the report beside the scene's own held-out figures.
#[derive(Debug, Clone, Default)]
pub struct Log {
    /// Validation score per variant at the main size (and the untrained
    /// baselines), per data and training seed.
    pub validation: Report,
    /// Variant → condition → the validation error of every training at the
    /// main size.
    pub validation_per_condition: BTreeMap<String, BTreeMap<String, Vec<f64>>>,
    /// Per training (`{variant}[_{size}]_data_{ds}_seed_{seed}`): its
    /// validation curve, the kept iteration and the validation failures.
    pub validation_curves: BTreeMap<String, Value>,
    /// Per variant (and size off the main one): each training's wall time.
    pub train_seconds: BTreeMap<String, Vec<f64>>,
    /// The learning rates chosen per family and data seed, and the pilots'
    /// scores ([`super::LearningRates::record`]).
    pub learning_rates: Map<String, Value>,
    /// Data seed → the unroll of the SOL variant selected on validation.
    pub selected_k: Map<String, Value>,
    /// Data seed → the size selected with it.
    pub selected_size: Map<String, Value>,
    /// Data seed → `(trained models, baseline readings)` of its held-out
    /// split in this run.
    pub held_out_readings: BTreeMap<u64, (usize, usize)>,
    /// Data seed → its split's tally in the output folder's ledger.
    pub held_out_evaluations: Map<String, Value>,
}

impl Log {
    /// An untrained baseline (`src`): its validation score and its error per
    /// condition.
    pub fn baseline(&mut self, name: &str, ds: u64, score: f64, per_condition: &[(String, f64)]) {
        self.validation.add(name, ds, None, score);
        for (condition, e) in per_condition {
            self.per_condition(name, condition, *e);
        }
    }

    fn per_condition(&mut self, name: &str, condition: &str, e: f64) {
        self.validation_per_condition
            .entry(name.to_string())
            .or_default()
            .entry(condition.to_string())
            .or_default()
            .push(e);
    }

    /// A training of data seed `ds`: at the `main` size its validation score
    /// and its error at each of `conditions` (the validation split's, in
    /// order); at every size its curve and wall time.
    pub fn training<S: PartialEq + Display>(
        &mut self,
        ds: u64,
        run: &TrainedRun<S>,
        main: S,
        conditions: &[String],
    ) {
        let (variant, seed, t) = (run.job.variant, run.job.seed.0, &run.trained.model);
        let key = if run.job.size == main {
            self.validation
                .add(&variant.name(), ds, Some(seed), t.validation);
            for (c, e) in conditions.iter().zip(&run.validation_per_condition) {
                self.per_condition(&variant.name(), c, *e);
            }
            variant.name()
        } else {
            format!("{variant}_{}", run.job.size)
        };
        self.validation_curves.insert(
            format!("{key}_data_{ds}_seed_{seed}"),
            json!({"curve": t.validation_curve, "kept_iteration": t.best_iteration,
                   "failures": t.validation_failures}),
        );
        self.train_seconds.entry(key).or_default().push(run.seconds);
    }

    /// The SOL variant and size selected on validation for data seed `ds`;
    /// prints it.
    pub fn selected(&mut self, ds: u64, variant: Variant, size: impl Display) {
        println!("  selected by validation: {variant} at {size}");
        self.selected_k
            .insert(ds.to_string(), json!(variant.unroll()));
        self.selected_size
            .insert(ds.to_string(), json!(size.to_string()));
    }

    /// Appends this run's held-out readings to the ledger in `dir`: per data
    /// seed, the split `split(ds)` (what identifies its data) read by models
    /// of `configuration` (everything that shaped them); prints each tally.
    ///
    /// # Errors
    /// [`crate::LearnError::Cache`] if the ledger cannot be read or written.
    pub fn count_readings(
        &mut self,
        dir: &Path,
        split: impl Fn(u64) -> String,
        configuration: &str,
    ) -> Result<()> {
        let ledger = Ledger::open(dir)?;
        for (&ds, &readings) in &self.held_out_readings {
            let tally = ledger.record(&split(ds), configuration, readings)?;
            println!(
                "data seed {ds}: held-out split read by {} run(s) of this configuration, {} of any ({} configuration(s), {} trained models in all; {})",
                tally.runs_of_this_configuration,
                tally.runs_of_any_configuration,
                tally.configurations,
                tally.trained_models,
                ledger.path().display()
            );
            self.held_out_evaluations
                .insert(format!("data_{ds}"), json!(tally));
        }
        Ok(())
    }

    /// The JSON keys of the log: `learning_rate`, `validation_rel_error`,
    /// `validation_per_{condition}` (summaries over the trainings),
    /// `selected_k`, `selected_size`, `selected_by`, `train_seconds`,
    /// `validation_curves`, `held_out_readings` and `held_out_evaluations`.
    pub fn to_json(&self, condition: &str) -> Map<String, Value> {
        let per_condition: Map<String, Value> = self
            .validation_per_condition
            .iter()
            .map(|(v, per)| {
                let stats: Map<String, Value> = per
                    .iter()
                    .map(|(c, e)| (c.clone(), json!(Summary::of(e))))
                    .collect();
                (v.clone(), Value::Object(stats))
            })
            .collect();
        let readings: Map<String, Value> = self
            .held_out_readings
            .iter()
            .map(|(ds, (models, baselines))| {
                let reading = json!({"trained_models": models, "baseline_readings": baselines});
                (format!("data_{ds}"), reading)
            })
            .collect();
        let mut out = Map::new();
        out.insert("learning_rate".into(), self.learning_rates.clone().into());
        out.insert(
            "validation_rel_error".into(),
            self.validation.summaries().into(),
        );
        out.insert(format!("validation_per_{condition}"), per_condition.into());
        out.insert("selected_k".into(), self.selected_k.clone().into());
        out.insert("selected_size".into(), self.selected_size.clone().into());
        out.insert("selected_by".into(), json!("validation"));
        out.insert("train_seconds".into(), json!(self.train_seconds));
        out.insert("validation_curves".into(), json!(self.validation_curves));
        out.insert("held_out_readings".into(), readings.into());
        out.insert(
            "held_out_evaluations".into(),
            self.held_out_evaluations.clone().into(),
        );
        out
    }

    /// Every training's validation curve as one chart at `path` (log y;
    /// nothing is written without curves).
    ///
    /// # Errors
    /// [`crate::LearnError::Report`] if the chart cannot be written.
    pub fn validation_chart(&self, path: &Path, y_label: &str) -> Result<()> {
        let series: Vec<Series> = self
            .validation_curves
            .iter()
            .filter_map(|(name, v)| {
                let points: Vec<(f64, f64)> = v["curve"]
                    .as_array()?
                    .iter()
                    .filter_map(|p| Some((p[0].as_f64()?, p[1].as_f64()?)))
                    .filter(|(_, y)| y.is_finite())
                    .collect();
                (!points.is_empty()).then(|| Series::new(name.clone(), points))
            })
            .collect();
        chart_unless_empty(
            path,
            &LineChart {
                title: "Validation error during training (mean over the rollout)",
                x_label: "Adam iteration",
                y_label,
                log_x: false,
                log_y: true,
                series: &series,
            },
        )
    }
}
