//! Results over data seeds × training seeds: per method every run, and the mean,
//! minimum and maximum over them.

use std::collections::BTreeMap;

use serde::Serialize;
use serde_json::{json, Value};

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
}
