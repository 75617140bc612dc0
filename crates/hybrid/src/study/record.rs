//! What a hybrid flow study keeps for its report: each model's held-out
//! rollouts per Reynolds number ([`HeldOutRun`]), every run's figures under
//! the four held-out metrics ([`Results`]), and the whole record of a run
//! ([`Record`]: the study's log, the results, the capacity sweep, the noise
//! scale and the pinned-face error).

use std::collections::BTreeMap;

use diffphys_flow::FlowState;
use diffphys_learn::study::{Log, Sweep};
use diffphys_learn::{Figures, Summary};
use serde_json::{json, Map, Value};

use crate::reference::Rollouts;
use crate::{NetSize, Result};

/// The held-out metrics: the state's relative L2 error over the rollouts
/// (the first, primary one), over the long rollout, the deviation's from the
/// free stream and the vorticity's.
pub const METRICS: [&str; 4] = [STATE, LONG, DEVIATION, VORTICITY];
/// The state's relative L2 error over the short rollouts.
pub const STATE: &str = "state";
/// The state's relative L2 error over the long rollout.
pub const LONG: &str = "long";
/// The relative L2 error of the velocity's deviation from the free stream.
pub const DEVIATION: &str = "deviation";
/// The vorticity's relative L2 error.
pub const VORTICITY: &str = "vorticity";

/// The figures of the capacity sweep's runs, in order: the state's error
/// over the rollouts (the sweep's primary, keyed by the variant alone), over
/// the long rollout, and the deviation's over the rollouts.
pub const SWEEP_FIGURES: [&str; 3] = ["", LONG, DEVIATION];

/// One run's figure over a baseline's of the same data seed
/// ([`Record::ratio_per_run`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunRatio {
    /// The run's data seed.
    pub data_seed: u64,
    /// Its training seed (`None` for a baseline).
    pub train_seed: Option<u64>,
    /// Its figure over the baseline's (`None` without a baseline run).
    pub ratio: Option<f64>,
}

impl RunRatio {
    /// `{"data_seed", "train_seed", "ratio"}`.
    pub fn to_json(self) -> Value {
        json!({"data_seed": self.data_seed, "train_seed": self.train_seed, "ratio": self.ratio})
    }
}

/// One model's held-out rollouts at every held-out Reynolds number.
#[derive(Debug, Clone)]
pub struct HeldOutRun {
    /// Per Reynolds number.
    pub per_re: Vec<Rollouts>,
}

impl HeldOutRun {
    /// The mean over the Reynolds numbers of the rollout error.
    pub fn mean(&self) -> f64 {
        self.per_re.iter().map(|r| r.mean).sum::<f64>() / self.per_re.len().max(1) as f64
    }

    /// The same for the long rollout.
    pub fn long_mean(&self) -> f64 {
        self.per_re.iter().map(|r| r.long).sum::<f64>() / self.per_re.len().max(1) as f64
    }

    /// The same for the deviation from the free stream.
    pub fn deviation_mean(&self) -> f64 {
        self.per_re.iter().map(|r| r.deviation).sum::<f64>() / self.per_re.len().max(1) as f64
    }

    /// The per-step error, mean over the Reynolds numbers.
    pub fn curve(&self) -> Vec<f64> {
        let n = self.per_re.len().max(1) as f64;
        let steps = self.per_re.first().map_or(0, |r| r.curve.len());
        (0..steps)
            .map(|t| self.per_re.iter().map(|r| r.curve[t]).sum::<f64>() / n)
            .collect()
    }

    /// Per Reynolds number, the four figures:
    /// `{"Re": {"mean": .., "long": .., "deviation": .., "vorticity": ..}}`.
    pub fn per_re_json(&self) -> Value {
        self.per_re
            .iter()
            .map(|r| {
                let errors = json!({"mean": r.mean, "long": r.long, "deviation": r.deviation,
                                    "vorticity": r.vorticity});
                (r.re.to_string(), errors)
            })
            .collect::<Map<String, Value>>()
            .into()
    }
}

/// The held-out figures of every run under [`METRICS`], and the long
/// rollouts' last states at the first held-out Re (one per method).
#[derive(Debug, Clone)]
pub struct Results {
    /// Every run's figures, overall and per Reynolds number.
    pub figures: Figures,
    /// Method → the long rollout's last state at the first held-out Re.
    pub last: BTreeMap<String, FlowState<f64>>,
}

impl Default for Results {
    fn default() -> Self {
        Results {
            figures: Figures::new(&METRICS),
            last: BTreeMap::new(),
        }
    }
}

impl Results {
    /// Records `run` of `name` from data seed `ds` and training seed `ts`.
    ///
    /// # Errors
    /// [`crate::HybridError::Learn`] for a run without a Reynolds number.
    pub fn record(&mut self, name: &str, ds: u64, ts: Option<u64>, run: &HeldOutRun) -> Result<()> {
        let per_re: Vec<(String, Vec<f64>)> = run
            .per_re
            .iter()
            .map(|r| {
                (
                    format!("{}", r.re),
                    vec![r.mean, r.long, r.deviation, r.vorticity],
                )
            })
            .collect();
        self.figures.add(name, (ds, ts), &per_re, run.curve())?;
        if let Some(r) = run.per_re.first() {
            self.last
                .entry(name.to_string())
                .or_insert_with(|| r.last.clone());
        }
        Ok(())
    }

    /// The summary over its runs of every method under `metric`.
    pub fn summaries(&self, metric: &str) -> Map<String, Value> {
        self.figures
            .report(metric)
            .map(|r| r.summaries())
            .unwrap_or_default()
    }
}

/// A study's record over every data seed.
#[derive(Debug, Clone)]
pub struct Record {
    /// The trainings, selections and held-out readings.
    pub log: Log,
    /// The held-out figures.
    pub results: Results,
    /// The capacity sweep's held-out figures (the state over the rollouts,
    /// the long rollout, the deviation over the rollouts) of `non` and the
    /// first SOL variant (`sol`) at every size.
    pub capacity: Sweep,
    /// The input noise of `noise` (the last data seed's).
    pub sigma: f64,
    /// Data seed → Re → the error on the faces the coarse step pins.
    pub pinned_face_error: Map<String, Value>,
}

impl Default for Record {
    fn default() -> Self {
        Record {
            log: Log::default(),
            results: Results::default(),
            capacity: Sweep::new(&SWEEP_FIGURES),
            sigma: 0.0,
            pinned_face_error: Map::new(),
        }
    }
}

impl Record {
    /// Prints the held-out tables (the rollouts' error and the long
    /// rollout's, against `src`).
    pub fn print_tables(&self) {
        for (title, metric) in [
            ("held-out mean relative L2 error over the rollouts:", STATE),
            ("long rollout:", LONG),
        ] {
            if let Some(r) = self.results.figures.report(metric) {
                println!("{title}");
                print!("{}", r.table(Some("src")));
            }
        }
    }

    /// The charts in `out`: `validation.svg` (every training's validation
    /// curve), `relative_error.svg` (held-out error per step),
    /// `capacity.svg` (error against corrector size, 100 steps and long, of
    /// `non` and, with `sol`, the first SOL) and `vorticity.svg` (the long
    /// rollouts' last states at the first held-out Re on `scene`, with the
    /// body's circle `(centre, radius)` outlined). A chart without data is
    /// not written.
    ///
    /// # Errors
    /// [`crate::HybridError::Learn`] if a chart cannot be written.
    pub fn charts(
        &self,
        out: &std::path::Path,
        scene: &diffphys_flow::Scene,
        body: ([f64; 2], f64),
        sol: bool,
    ) -> Result<()> {
        let u = "|u - u_ref| / |u_ref|";
        self.log.validation_chart(&out.join("validation.svg"), u)?;
        self.results.figures.curves_chart(
            &out.join("relative_error.svg"),
            "Held-out rollouts: relative L2 error per step (mean over Re, starts, seeds)",
            u,
        )?;
        let mut lines = vec![("non", 0, "non, 100 steps"), ("non", 1, "non, long")];
        if sol {
            lines.extend([("sol", 0, "sol, 100 steps"), ("sol", 1, "sol, long")]);
        }
        self.capacity.chart(
            &out.join("capacity.svg"),
            "Held-out error against corrector size (mean over Re and seeds)",
            &lines,
        )?;
        // The reference first, then the solvers in the order of the report.
        let order = ["reference", "src", "non", "noise", "sol_selected"];
        let states: Vec<(&str, &FlowState<f64>)> = (order.iter())
            .filter_map(|&n| Some((n, self.results.last.get(n)?)))
            .collect();
        let title = "Vorticity after the long rollout, first held-out Re";
        crate::metrics::vorticity_chart(&out.join("vorticity.svg"), title, &states, scene, body)
    }

    /// Per held-out Re, the mean of method `a` over that of `b` under
    /// `metric` (`None` where either was not measured).
    pub fn ratio_per_re(&self, a: &str, b: &str, metric: &str) -> BTreeMap<String, Option<f64>> {
        let f = &self.results.figures;
        (f.conditions())
            .map(|re| {
                let mean = |m: &str| f.mean_at(re, m, metric);
                let ratio = mean(a).zip(mean(b)).map(|(a, b)| a / b);
                (re.to_string(), ratio)
            })
            .collect()
    }

    /// Per held-out Re, every run of `a` over the mean of `b`'s runs of the
    /// same data seed under `metric` (a run whose data seed has no run of
    /// `b` has no ratio).
    pub fn ratio_per_run(&self, a: &str, b: &str, metric: &str) -> BTreeMap<String, Vec<RunRatio>> {
        let f = &self.results.figures;
        (f.conditions())
            .map(|re| {
                let base = f.runs_at(re, b, metric);
                let ratios = (f.runs_at(re, a, metric).into_iter())
                    .map(|r| {
                        let same: Vec<f64> = (base.iter())
                            .filter(|q| q.data_seed == r.data_seed)
                            .map(|q| q.value)
                            .collect();
                        let mean = Summary::of(&same).map(|s| s.mean);
                        RunRatio {
                            data_seed: r.data_seed,
                            train_seed: r.train_seed,
                            ratio: mean.map(|m| r.value / m),
                        }
                    })
                    .collect();
                (re.to_string(), ratios)
            })
            .collect()
    }

    /// The record's JSON keys: the held-out summaries under every metric
    /// (`mean_rel_error`, `long_rel_error`, `deviation_rel_error`,
    /// `vorticity_rel_error`), `per_re`, `noise_sigma` and the log's
    /// ([`Log::to_json`], conditions named `re`).
    pub fn to_json(&self) -> Map<String, Value> {
        let mut out = self.log.to_json("re");
        for (key, metric) in [
            ("mean_rel_error", STATE),
            ("long_rel_error", LONG),
            ("deviation_rel_error", DEVIATION),
            ("vorticity_rel_error", VORTICITY),
        ] {
            out.insert(key.into(), self.results.summaries(metric).into());
        }
        out.insert("per_re".into(), self.results.figures.per_condition_json());
        out.insert("noise_sigma".into(), json!(self.sigma));
        out
    }
}

/// A saved model's directory name: `sol_4_w16b2_data1_seed2`.
pub fn dir_name(variant: &str, size: NetSize, data_seed: u64, seed: u64) -> String {
    format!("{variant}_{}_data{data_seed}_seed{seed}", size.label())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    fn run(per_re: &[(f64, f64, f64)]) -> HeldOutRun {
        let z = Array2::zeros((1, 1));
        let last = FlowState {
            ux: z.clone(),
            uy: z.clone(),
            pressure: z,
            scalars: Vec::new(),
        };
        HeldOutRun {
            per_re: (per_re.iter())
                .map(|&(re, mean, deviation)| Rollouts {
                    re,
                    mean,
                    deviation,
                    vorticity: 0.0,
                    curve: vec![mean],
                    long: mean,
                    last: last.clone(),
                })
                .collect(),
        }
    }

    #[test]
    fn ratios_per_run_divide_by_the_same_data_seed() {
        let mut r = Record::default();
        let results = &mut r.results;
        results
            .record("src", 1, None, &run(&[(65.0, 0.2, 1.0), (250.0, 0.4, 2.0)]))
            .unwrap();
        results
            .record("src", 2, None, &run(&[(65.0, 0.1, 0.5), (250.0, 0.2, 1.0)]))
            .unwrap();
        for (ds, ts, d) in [(1, 1, 0.2), (1, 2, 0.4), (2, 1, 0.1)] {
            let sol = run(&[(65.0, 0.01, d), (250.0, 0.02, 2.0 * d)]);
            results.record("sol", ds, Some(ts), &sol).unwrap();
        }
        let per_run = r.ratio_per_run("sol", "src", DEVIATION);
        let ratios: Vec<_> = per_run["65"]
            .iter()
            .map(|r| (r.data_seed, r.train_seed, r.ratio.unwrap()))
            .collect();
        let expected = [(1, Some(1), 0.2), (1, Some(2), 0.4), (2, Some(1), 0.2)];
        for ((ds, ts, q), (eds, ets, eq)) in ratios.iter().zip(expected) {
            assert_eq!((*ds, *ts), (eds, ets));
            assert!((q - eq).abs() < 1e-14, "{q} against {eq}");
        }
        // On the mean over the runs: (0.7 / 3) / 0.75 under the deviation,
        // 0.01 / 0.15 under the state.
        let on_mean = r.ratio_per_re("sol", "src", DEVIATION)["65"].unwrap();
        assert!((on_mean - 0.7 / 3.0 / 0.75).abs() < 1e-14);
        let state = r.ratio_per_re("sol", "src", STATE)["65"].unwrap();
        assert!((state - 0.01 / 0.15).abs() < 1e-14);
        // A method never run has no ratio.
        assert!(r.ratio_per_run("non", "src", DEVIATION)["65"].is_empty());
        assert!(r.ratio_per_re("non", "src", DEVIATION)["65"].is_none());
    }
}
