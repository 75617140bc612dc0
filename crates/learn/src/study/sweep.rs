//! A capacity sweep: the same variants trained at several model sizes, each
//! run scored by one or more figures.

use diffphys_report::chart::{LineChart, Series};
use serde_json::{json, Map, Value};

use crate::report::{chart_unless_empty, Summary};
use crate::Result;

/// One trained model of a sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepRun {
    /// The model's size, as a label (`w16b2`).
    pub size: String,
    /// Its parameter count.
    pub params: usize,
    /// The variant it was trained as (`non`, `sol`).
    pub variant: String,
    /// Its training seed.
    pub seed: u64,
    /// Its figures, one per name of the sweep.
    pub figures: Vec<f64>,
}

/// Every run of a capacity sweep, scored by the figures named at
/// [`Sweep::new`] (the first is the primary one).
///
/// ```
/// use diffphys_learn::study::{Sweep, SweepRun};
///
/// let mut sweep = Sweep::new(&["", "long"]);
/// for (size, params, variant, e) in [("w8b1", 1538, "non", 0.1), ("w8b1", 1538, "sol", 0.05), ("w16b2", 10018, "sol", 0.04)] {
///     sweep.add(SweepRun { size: size.into(), params, variant: variant.into(), seed: 1, figures: vec![e, 2.0 * e] });
/// }
/// assert_eq!(sweep.ratio("w8b1", "sol", "non", 0), Some(0.5));
/// assert_eq!(sweep.series("sol", 1), vec![(1538.0, 0.1), (10018.0, 0.08)]);
/// let j = sweep.to_json(&["non", "sol"]);
/// assert_eq!(j["rows"][0]["size"], "w8b1");
/// assert_eq!(j["rows"][0]["sol_long"]["mean"], 0.1);
/// ```
#[derive(Debug, Clone, Default)]
pub struct Sweep {
    names: Vec<String>,
    runs: Vec<SweepRun>,
}

impl Sweep {
    /// A sweep whose runs carry one figure per name; the first name is the
    /// primary figure's (its JSON key is the variant alone, the others'
    /// `variant_name`).
    pub fn new(names: &[&str]) -> Self {
        Sweep {
            names: names.iter().map(|n| n.to_string()).collect(),
            runs: Vec::new(),
        }
    }

    /// Records a run.
    pub fn add(&mut self, run: SweepRun) {
        self.runs.push(run);
    }

    /// Every run, in the order added.
    pub fn runs(&self) -> &[SweepRun] {
        &self.runs
    }

    /// Figure `k` of every run of `variant` at `size`.
    fn values(&self, size: &str, variant: &str, k: usize) -> Vec<f64> {
        self.runs
            .iter()
            .filter(|r| r.size == size && r.variant == variant)
            .filter_map(|r| r.figures.get(k).copied())
            .collect()
    }

    /// `mean(a) / mean(b)` of figure `k` at `size`, when both were run.
    pub fn ratio(&self, size: &str, a: &str, b: &str, k: usize) -> Option<f64> {
        let mean = |v: &str| Summary::of(&self.values(size, v, k)).map(|s| s.mean);
        Some(mean(a)? / mean(b)?)
    }

    /// The sizes, smallest parameter count first: `(label, params)`.
    fn sizes(&self) -> Vec<(&str, usize)> {
        let mut sizes: Vec<(&str, usize)> = self
            .runs
            .iter()
            .map(|r| (r.size.as_str(), r.params))
            .collect();
        sizes.sort_by_key(|&(_, p)| p);
        sizes.dedup();
        sizes
    }

    /// `(params, mean of figure k)` of `variant` at every size it was run
    /// at, smallest first: a curve of the figure against capacity.
    pub fn series(&self, variant: &str, k: usize) -> Vec<(f64, f64)> {
        self.sizes()
            .into_iter()
            .filter_map(|(size, params)| {
                let s = Summary::of(&self.values(size, variant, k))?;
                Some((params as f64, s.mean))
            })
            .collect()
    }

    /// `{"rows": [{"size", "params", "<variant>": summary, "<variant>_<name>": summary, ...}]}`,
    /// one row per size (smallest first), for each of `variants`.
    pub fn to_json(&self, variants: &[&str]) -> Value {
        let rows: Vec<Value> = self
            .sizes()
            .into_iter()
            .map(|(size, params)| {
                let mut row = Map::new();
                row.insert("size".into(), json!(size));
                row.insert("params".into(), json!(params));
                for (k, name) in self.names.iter().enumerate() {
                    for v in variants {
                        let key = if name.is_empty() {
                            v.to_string()
                        } else {
                            format!("{v}_{name}")
                        };
                        row.insert(key, json!(Summary::of(&self.values(size, v, k))));
                    }
                }
                Value::Object(row)
            })
            .collect();
        json!({ "rows": rows })
    }

    /// Error against model size (parameters, log-log) at `path`: one line
    /// per `(variant, figure, label)` of `lines` ([`Sweep::series`]); lines
    /// without runs are left out, and nothing is written without any.
    ///
    /// # Errors
    /// [`crate::LearnError::Report`] if the chart cannot be written.
    pub fn chart(
        &self,
        path: &std::path::Path,
        title: &str,
        lines: &[(&str, usize, &str)],
    ) -> Result<()> {
        let series: Vec<Series> = lines
            .iter()
            .map(|&(variant, k, label)| Series::new(label, self.series(variant, k)))
            .filter(|s| !s.points.is_empty())
            .collect();
        chart_unless_empty(
            path,
            &LineChart {
                title,
                x_label: "parameters",
                y_label: "mean relative L2 error",
                log_x: true,
                log_y: true,
                series: &series,
            },
        )
    }
}
