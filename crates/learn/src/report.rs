//! Results over data seeds × training seeds: per method every run, and the mean,
//! minimum and maximum over them ([`Report`]); several metrics of every run,
//! overall and per condition (a Reynolds number, say), with per-step curves
//! ([`Figures`]).

use std::collections::BTreeMap;

use diffphys_report::chart::{line_chart_svg, LineChart, Series};
use serde::Serialize;
use serde_json::{json, Value};

use crate::{LearnError, Result};

/// The mean, minimum and maximum of a set of runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Summary {
    /// The mean.
    pub mean: f64,
    /// The smallest value.
    pub min: f64,
    /// The largest value.
    pub max: f64,
    /// How many runs.
    pub runs: usize,
}

impl Summary {
    /// The summary of `values`; `None` without values.
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        Some(Summary {
            mean: values.iter().sum::<f64>() / values.len() as f64,
            min: values.iter().copied().fold(f64::INFINITY, f64::min),
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            runs: values.len(),
        })
    }
}

/// A run's data seed and training seed (`None` for a baseline).
pub type RunSeeds = (u64, Option<u64>);

/// A method's runs at one condition: each run's seeds and its values, one
/// per metric.
type SeededRuns = Vec<(RunSeeds, Vec<f64>)>;

/// One run's figure.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RunRecord {
    /// The data seed (train, validation and held-out draws).
    pub data_seed: u64,
    /// The training seed (initialisation, sampling); `None` for a baseline
    /// without training.
    pub train_seed: Option<u64>,
    /// The figure (a held-out error, an iteration count, …).
    pub value: f64,
}

/// Per method, the figure of every run.
#[derive(Debug, Clone, Default)]
pub struct Report {
    methods: Vec<(String, Vec<RunRecord>)>,
}

impl Report {
    /// An empty report.
    pub fn new() -> Self {
        Report::default()
    }

    /// Records `value` for `method` from the run of `data_seed` and `train_seed`.
    pub fn add(&mut self, method: &str, data_seed: u64, train_seed: Option<u64>, value: f64) {
        let record = RunRecord {
            data_seed,
            train_seed,
            value,
        };
        match self.methods.iter_mut().find(|(m, _)| m == method) {
            Some((_, runs)) => runs.push(record),
            None => self.methods.push((method.to_string(), vec![record])),
        }
    }

    /// The methods in the order first added.
    pub fn methods(&self) -> impl Iterator<Item = &str> {
        self.methods.iter().map(|(m, _)| m.as_str())
    }

    /// Every run of `method`.
    pub fn runs(&self, method: &str) -> &[RunRecord] {
        self.methods
            .iter()
            .find(|(m, _)| m == method)
            .map_or(&[], |(_, r)| r.as_slice())
    }

    /// The summary over every run of `method`.
    pub fn summary(&self, method: &str) -> Option<Summary> {
        let values: Vec<f64> = self.runs(method).iter().map(|r| r.value).collect();
        Summary::of(&values)
    }

    /// The mean over training seeds per data seed, in data-seed order.
    pub fn per_data_seed(&self, method: &str) -> Vec<(u64, f64)> {
        let mut by_seed: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
        for r in self.runs(method) {
            by_seed.entry(r.data_seed).or_default().push(r.value);
        }
        by_seed
            .into_iter()
            .map(|(s, v)| (s, v.iter().sum::<f64>() / v.len() as f64))
            .collect()
    }

    /// Every method's [`Summary`] over its runs, by name (a method without
    /// runs left out).
    pub fn summaries(&self) -> serde_json::Map<String, Value> {
        self.methods()
            .filter_map(|m| self.summary(m).map(|s| (m.to_string(), json!(s))))
            .collect()
    }

    /// `{method: {mean, min, max, runs, per_data_seed: {seed: mean}, per_run:
    /// [{data_seed, train_seed, value}]}}`.
    pub fn to_json(&self) -> Value {
        let mut out = serde_json::Map::new();
        for (method, runs) in &self.methods {
            let summary = self.summary(method);
            let per_seed: serde_json::Map<String, Value> = self
                .per_data_seed(method)
                .into_iter()
                .map(|(s, v)| (s.to_string(), json!(v)))
                .collect();
            out.insert(
                method.clone(),
                json!({
                    "mean": summary.map(|s| s.mean),
                    "min": summary.map(|s| s.min),
                    "max": summary.map(|s| s.max),
                    "runs": runs.len(),
                    "per_data_seed": per_seed,
                    "per_run": runs,
                }),
            );
        }
        Value::Object(out)
    }

    /// A markdown table: method, mean, min, max, runs, and `mean / baseline`
    /// when `baseline` names a method.
    pub fn table(&self, baseline: Option<&str>) -> String {
        let base = baseline.and_then(|b| self.summary(b)).map(|s| s.mean);
        let mut s = String::from(
            "| method | mean | min | max | runs | mean / baseline |\n|---|---|---|---|---|---|\n",
        );
        for (method, _) in &self.methods {
            if let Some(m) = self.summary(method) {
                let ratio = base.map_or("".to_string(), |b| format!("{:.3}", m.mean / b));
                s.push_str(&format!(
                    "| {method} | {:.5} | {:.5} | {:.5} | {} | {ratio} |\n",
                    m.mean, m.min, m.max, m.runs
                ));
            }
        }
        s
    }
}

/// Every run's figures under several metrics, overall and per condition
/// (each held-out Reynolds number, say), with its per-step curve.
///
/// A run gives one value per metric at each condition; its overall figure
/// under a metric is the mean over its conditions, kept in one [`Report`]
/// per metric. The first metric is the primary one: per condition it is
/// summarised with its minimum and maximum, the others by their means
/// ([`Figures::per_condition_json`]).
#[derive(Debug, Clone, Default)]
pub struct Figures {
    metrics: Vec<String>,
    overall: Vec<Report>,
    /// Condition → method → runs → the run's seeds and one value per metric.
    per_condition: BTreeMap<String, BTreeMap<String, SeededRuns>>,
    curves: BTreeMap<String, Vec<Vec<f64>>>,
}

impl Figures {
    /// Figures under `metrics`, the first the primary one.
    pub fn new(metrics: &[&str]) -> Self {
        Figures {
            metrics: metrics.iter().map(|m| m.to_string()).collect(),
            overall: vec![Report::new(); metrics.len()],
            ..Figures::default()
        }
    }

    /// Records the run of `method` from `data_seed` and `train_seed`: its
    /// values at each condition (one per metric, in order) and its per-step
    /// curve.
    ///
    /// # Errors
    /// [`LearnError::Invalid`] without a condition or for a condition with
    /// another number of values than metrics.
    pub fn add(
        &mut self,
        method: &str,
        (data_seed, train_seed): (u64, Option<u64>),
        per_condition: &[(String, Vec<f64>)],
        curve: Vec<f64>,
    ) -> Result<()> {
        let invalid = |message: String| LearnError::Invalid {
            what: "figures",
            message,
        };
        if per_condition.is_empty() {
            return Err(invalid(format!("a run of {method} at no condition")));
        }
        if let Some((c, v)) = per_condition
            .iter()
            .find(|(_, v)| v.len() != self.metrics.len())
        {
            return Err(invalid(format!(
                "{} values at {c} for {} metrics",
                v.len(),
                self.metrics.len()
            )));
        }
        let n = per_condition.len() as f64;
        for (k, report) in self.overall.iter_mut().enumerate() {
            let mean = per_condition.iter().map(|(_, v)| v[k]).sum::<f64>() / n;
            report.add(method, data_seed, train_seed, mean);
        }
        for (c, v) in per_condition {
            self.per_condition
                .entry(c.clone())
                .or_default()
                .entry(method.to_string())
                .or_default()
                .push(((data_seed, train_seed), v.clone()));
        }
        self.curves
            .entry(method.to_string())
            .or_default()
            .push(curve);
        Ok(())
    }

    /// Every run's overall figure under `metric`.
    pub fn report(&self, metric: &str) -> Option<&Report> {
        let k = self.metrics.iter().position(|m| m == metric)?;
        self.overall.get(k)
    }

    /// Per method, every run's per-step curve.
    pub fn curves(&self) -> &BTreeMap<String, Vec<Vec<f64>>> {
        &self.curves
    }

    /// Each method's per-step curve, mean over its runs, as one chart at
    /// `path` (log y; nothing is written without curves).
    ///
    /// # Errors
    /// [`LearnError::Report`] if the chart cannot be written.
    pub fn curves_chart(&self, path: &std::path::Path, title: &str, y_label: &str) -> Result<()> {
        let series: Vec<Series> = self
            .curves
            .iter()
            .map(|(name, c)| Series::mean_per_step(name.clone(), c))
            .filter(|s| !s.points.is_empty())
            .collect();
        chart_unless_empty(
            path,
            &LineChart {
                title,
                x_label: "step",
                y_label,
                log_x: false,
                log_y: true,
                series: &series,
            },
        )
    }

    /// The conditions, in order.
    pub fn conditions(&self) -> impl Iterator<Item = &str> {
        self.per_condition.keys().map(String::as_str)
    }

    /// The mean over the runs of `method` at `condition` under `metric`.
    pub fn mean_at(&self, condition: &str, method: &str, metric: &str) -> Option<f64> {
        let k = self.metrics.iter().position(|m| m == metric)?;
        let runs = self.per_condition.get(condition)?.get(method)?;
        Summary::of(&runs.iter().map(|(_, v)| v[k]).collect::<Vec<_>>()).map(|s| s.mean)
    }

    /// Every run of `method` at `condition` under `metric`, with its seeds,
    /// in the order added (empty where there is none).
    pub fn runs_at(&self, condition: &str, method: &str, metric: &str) -> Vec<RunRecord> {
        let Some(k) = self.metrics.iter().position(|m| m == metric) else {
            return Vec::new();
        };
        (self.per_condition.get(condition))
            .and_then(|m| m.get(method))
            .map(|runs| {
                runs.iter()
                    .map(|&((data_seed, train_seed), ref v)| RunRecord {
                        data_seed,
                        train_seed,
                        value: v[k],
                    })
                    .collect()
            })
            .unwrap_or_default()
    }

    /// `{condition: {method: {mean, min, max, runs, <metric>_mean, ...}}}`:
    /// the primary metric's mean, minimum and maximum over the runs, and each
    /// other metric's mean.
    pub fn per_condition_json(&self) -> Value {
        let methods = |m: &BTreeMap<String, SeededRuns>| -> serde_json::Map<String, Value> {
            m.iter()
                .filter_map(|(method, runs)| {
                    let of = |k: usize| Summary::of(&runs.iter().map(|(_, v)| v[k]).collect::<Vec<_>>());
                    let primary = of(0)?;
                    let mut entry = json!({"mean": primary.mean, "min": primary.min, "max": primary.max, "runs": primary.runs});
                    for (k, name) in self.metrics.iter().enumerate().skip(1) {
                        entry[format!("{name}_mean")] = json!(of(k).map(|s| s.mean));
                    }
                    Some((method.clone(), entry))
                })
                .collect()
        };
        self.per_condition
            .iter()
            .map(|(c, m)| (c.clone(), Value::Object(methods(m))))
            .collect::<serde_json::Map<_, _>>()
            .into()
    }
}

/// Writes `chart` at `path` unless it has no series (a report skips a chart
/// it has nothing for).
pub(crate) fn chart_unless_empty(path: &std::path::Path, chart: &LineChart<'_>) -> Result<()> {
    if chart.series.is_empty() {
        return Ok(());
    }
    Ok(line_chart_svg(path, chart)?)
}

/// The floors of a `floors_met` JSON object that are not met: its `false`
/// entries whose name does not start with `goal_` (a goal is reported, not
/// required). A floor a run did not measure (a string such as `"not
/// measured"`) neither holds nor fails; a value that is not an object is one
/// missed floor (`floors_met (not reported)`).
pub fn missed_floors(floors: &Value) -> Vec<String> {
    let Some(entries) = floors.as_object() else {
        return vec!["floors_met (not reported)".into()];
    };
    entries
        .iter()
        .filter(|(name, _)| !name.starts_with("goal_"))
        .filter_map(|(name, v)| match v {
            Value::Bool(false) => Some(name.clone()),
            _ => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summaries_over_seeds() {
        let mut r = Report::new();
        r.add("non", 1, Some(1), 2.0);
        r.add("non", 1, Some(2), 4.0);
        r.add("non", 2, Some(1), 6.0);
        let s = r.summary("non").unwrap();
        assert_eq!((s.mean, s.min, s.max, s.runs), (4.0, 2.0, 6.0, 3));
        assert_eq!(r.per_data_seed("non"), vec![(1, 3.0), (2, 6.0)]);
        assert!(r.summary("sol").is_none());
        let j = r.to_json();
        assert_eq!(j["non"]["mean"], 4.0);
        assert_eq!(j["non"]["per_run"][2]["data_seed"], 2);
        assert!(Summary::of(&[]).is_none());
    }

    #[test]
    fn figures_per_condition_and_overall() {
        let mut f = Figures::new(&["state", "long"]);
        let at = |a: f64, b: f64| {
            vec![
                ("71".to_string(), vec![a, 10.0 * a]),
                ("283".to_string(), vec![b, 10.0 * b]),
            ]
        };
        f.add("src", (1, None), &at(0.2, 0.4), vec![0.1, 0.2])
            .unwrap();
        f.add("sol", (1, Some(1)), &at(0.02, 0.06), vec![0.01])
            .unwrap();
        f.add("sol", (1, Some(2)), &at(0.04, 0.08), vec![0.03])
            .unwrap();
        let state = f.report("state").unwrap();
        assert!((state.summary("src").unwrap().mean - 0.3).abs() < 1e-15);
        assert!((state.summary("sol").unwrap().mean - 0.05).abs() < 1e-15);
        assert!((f.report("long").unwrap().summary("sol").unwrap().max - 0.6).abs() < 1e-15);
        assert!(f.report("vorticity").is_none());
        assert!((f.mean_at("71", "sol", "state").unwrap() - 0.03).abs() < 1e-15);
        assert!(f.mean_at("71", "non", "state").is_none());
        let runs = f.runs_at("283", "sol", "long");
        assert_eq!(
            runs.iter()
                .map(|r| (r.data_seed, r.train_seed))
                .collect::<Vec<_>>(),
            vec![(1, Some(1)), (1, Some(2))]
        );
        assert!((runs[1].value - 0.8).abs() < 1e-15);
        assert!(f.runs_at("283", "sol", "vorticity").is_empty());
        assert!(f.runs_at("85", "sol", "state").is_empty());
        assert_eq!(f.conditions().collect::<Vec<_>>(), vec!["283", "71"]);
        let j = f.per_condition_json();
        assert_eq!(j["71"]["sol"]["runs"], 2);
        assert_eq!(j["71"]["sol"]["min"], 0.02);
        assert!((j["283"]["src"]["long_mean"].as_f64().unwrap() - 4.0).abs() < 1e-15);
        assert_eq!(f.curves()["sol"].len(), 2);
        // A run without a condition, or with a value missing, is refused.
        assert!(f.add("non", (1, Some(1)), &[], vec![]).is_err());
        let short = vec![("71".to_string(), vec![0.1])];
        assert!(f.add("non", (1, Some(1)), &short, vec![]).is_err());
    }

    #[test]
    fn missed_floors_are_the_false_non_goals_and_unmeasured_ones_pass() {
        let floors = json!({"a": true, "b": false, "goal_c": false, "d": "not measured"});
        assert_eq!(missed_floors(&floors), vec!["b".to_string()]);
        assert_eq!(
            missed_floors(&json!(null)),
            vec!["floors_met (not reported)".to_string()]
        );
    }
}
