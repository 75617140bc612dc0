//! The warm-up and repetition policy every timed method of the harness gets.
//!
//! A first run pays for things a second does not: fresh pages for a large tape
//! (at 256², 775 unrolled iterations in `f64`, the first naive forward took
//! 4.5 s and the next 1.1 s), cold caches, lazily built tables. A ratio of two
//! methods must not depend on which of them ran first, so each timed method
//! runs [`TimingPolicy::warmup`] untimed times, then [`TimingPolicy::repeats`]
//! timed times, and its row reports the run picked by
//! [`TimingPolicy::statistic`] (all its figures from that one run, so forward
//! and backward add up), with every timed run's total in
//! [`ResultRow::run_times_s`](crate::report::ResultRow::run_times_s).
//!
//! Peak heap is the exception: the tape keeps the buffers of a dropped tape in
//! a pool ([`diffphys_tape::pool`]) for the next one, so a warm run allocates
//! almost nothing new. The harness therefore reads a method's peak heap in its
//! first run (warm-up or not), after emptying the pool.

use serde::{Deserialize, Serialize};

use crate::{CompareError, Result};

/// Which of the timed runs a row reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Statistic {
    /// The fastest run: the least disturbed by other work on the machine.
    Best,
    /// The run of median time (the lower median for an even count).
    Median,
}

impl Statistic {
    /// `best` or `median`.
    pub fn name(self) -> &'static str {
        match self {
            Statistic::Best => "best",
            Statistic::Median => "median",
        }
    }

    /// Parses `best` or `median`.
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] for anything else.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "best" => Ok(Statistic::Best),
            "median" => Ok(Statistic::Median),
            other => Err(CompareError::invalid(format!(
                "unknown statistic '{other}': expected best or median"
            ))),
        }
    }

    /// The index into `times` of the run this statistic picks (`None` if
    /// `times` is empty). Ties go to the earlier run.
    pub fn pick(self, times: &[f64]) -> Option<usize> {
        let mut order: Vec<usize> = (0..times.len()).collect();
        order.sort_by(|&a, &b| times[a].total_cmp(&times[b]).then(a.cmp(&b)));
        match self {
            Statistic::Best => order.first().copied(),
            Statistic::Median => order.get(times.len().saturating_sub(1) / 2).copied(),
        }
    }
}

impl std::fmt::Display for Statistic {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How each timed method is run: `warmup` untimed runs, then `repeats` timed
/// runs, of which `statistic` picks the one reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct TimingPolicy {
    /// Untimed runs first (their results are dropped).
    pub warmup: usize,
    /// Timed runs after the warm-up (at least 1).
    pub repeats: usize,
    /// Which timed run the row reports.
    pub statistic: Statistic,
}

impl Default for TimingPolicy {
    /// One warm-up, then the best of 3.
    fn default() -> Self {
        TimingPolicy {
            warmup: 1,
            repeats: 3,
            statistic: Statistic::Best,
        }
    }
}

impl TimingPolicy {
    /// One run, no warm-up: for studies that look at accuracy, not time.
    pub fn single() -> Self {
        TimingPolicy {
            warmup: 0,
            repeats: 1,
            statistic: Statistic::Best,
        }
    }

    /// The `--quick` policy: one warm-up, one timed run.
    pub fn quick() -> Self {
        TimingPolicy {
            warmup: 1,
            repeats: 1,
            statistic: Statistic::Best,
        }
    }

    /// Checks the policy.
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] if `repeats` is 0.
    pub fn validate(&self) -> Result<()> {
        if self.repeats == 0 {
            return Err(CompareError::invalid(
                "the timing policy needs at least one timed run (--repeat ≥ 1)",
            ));
        }
        Ok(())
    }

    /// The policy in words: `1 untimed warm-up run, then the best of 3 timed runs, …`.
    pub fn describe(&self) -> String {
        let warm = match self.warmup {
            0 => "no warm-up run".to_string(),
            1 => "1 untimed warm-up run".to_string(),
            k => format!("{k} untimed warm-up runs"),
        };
        let timed = match (self.repeats, self.statistic) {
            (1, _) => "1 timed run".to_string(),
            (r, Statistic::Best) => format!("the best of {r} timed runs"),
            (r, Statistic::Median) => format!("the median of {r} timed runs"),
        };
        format!(
            "{warm}, then {timed}, for every timed method; peak heap from the first run, \
             started with an empty tape buffer pool"
        )
    }

    /// Runs `run` `warmup + repeats` times, in that order, and returns the
    /// timed run that [`TimingPolicy::statistic`] picks by the seconds `seconds`
    /// reads from it, with every timed run's seconds in run order. Warm-up
    /// results are dropped before the next run starts.
    ///
    /// # Errors
    /// The first error of any run (warm-up included); [`TimingPolicy::validate`].
    pub fn run<R>(
        &self,
        mut run: impl FnMut() -> Result<R>,
        seconds: impl Fn(&R) -> f64,
    ) -> Result<Timed<R>> {
        self.validate()?;
        for _ in 0..self.warmup {
            drop(run()?);
        }
        let mut results = Vec::with_capacity(self.repeats);
        for _ in 0..self.repeats {
            results.push(run()?);
        }
        let times: Vec<f64> = results.iter().map(&seconds).collect();
        let picked = self.statistic.pick(&times).expect("at least one timed run");
        let value = results.swap_remove(picked);
        Ok(Timed {
            value,
            seconds: times[picked],
            picked,
            times,
        })
    }
}

/// The result of [`TimingPolicy::run`].
#[derive(Debug, Clone, PartialEq)]
pub struct Timed<R> {
    /// The picked run's result.
    pub value: R,
    /// The picked run's seconds.
    pub seconds: f64,
    /// The index of the picked run among the timed runs.
    pub picked: usize,
    /// Every timed run's seconds, in run order.
    pub times: Vec<f64>,
}
