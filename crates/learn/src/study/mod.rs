//! Studies: a plan of variants × sizes × training seeds, trained several at
//! once, grouped back per variant for selection on validation.
//!
//! A scene states its plan as values ([`Plan`]); [`Plan::jobs`] lists one
//! [`Job`] per training, [`run_jobs`] runs them on worker threads (each
//! training is deterministic for its seed, so the results do not depend on the
//! scheduling and come back in job order), and [`Plan::groups`] gives the
//! results back per `(variant, size)` with their training seeds, ready to be
//! made [`Candidate`]s labelled by the typed `(variant, size)`
//! itself. [`Protocol`] runs the whole protocol of one data seed: the
//! trainings, selection on validation, and each trained model's one held-out
//! evaluation; a [`Ledger`] counts the readings of each held-out split across
//! runs.
//!
//! ```
//! use diffphys_learn::study::{run_jobs, Plan};
//! use diffphys_learn::TrainSeed;
//!
//! #[derive(Debug, Clone, Copy, PartialEq)]
//! enum Variant { Non, Sol(usize) }
//! let plan = Plan::new(vec![(Variant::Non, 8), (Variant::Sol(4), 8)], vec![TrainSeed(1), TrainSeed(2)]);
//! let jobs = plan.jobs();
//! assert_eq!(jobs.len(), 4);
//! // A stand-in for a training: its "validation score".
//! let scores = run_jobs(&jobs, 2, |job| Ok::<_, String>(job.seed.0 as f64))?;
//! let groups = plan.groups(scores)?;
//! assert_eq!(groups[1].variant, Variant::Sol(4));
//! assert_eq!(groups[1].runs, vec![1.0, 2.0]);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod ledger;
mod log;
mod protocol;
mod sweep;
mod training;
mod variant;

pub use ledger::{Ledger, Reading, Tally, LEDGER_FILE};
pub use log::Log;
pub use protocol::{Entry, OneSize, Outcome, Protocol, Run};
pub use sweep::{Sweep, SweepRun};
pub use training::{LearningRates, NewCorrector, TrainJob, TrainedRun, Trainings};
pub use variant::Variant;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use crate::data::{select_best, Candidate, Selection, TrainSeed, Trained};
use crate::{LearnError, Result};

/// One training of a plan: a variant at a size, from a training seed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Job<V, S> {
    /// The variant (how it is trained: a strategy, a coupling).
    pub variant: V,
    /// The model's size.
    pub size: S,
    /// The training seed (initial parameters and sampling).
    pub seed: TrainSeed,
}

/// The results of one `(variant, size)` of a plan, one per training seed.
#[derive(Debug, Clone, PartialEq)]
pub struct Group<V, S, R> {
    /// The variant.
    pub variant: V,
    /// The size.
    pub size: S,
    /// The training seeds, in the plan's order.
    pub seeds: Vec<TrainSeed>,
    /// What each training returned, seed by seed.
    pub runs: Vec<R>,
}

/// What a study trains: every `(variant, size)` entry at every training seed.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan<V, S> {
    /// The `(variant, size)` entries, in the order they are trained (put the
    /// costliest first so that the workers finish together).
    pub entries: Vec<(V, S)>,
    /// The training seeds every entry is trained from.
    pub seeds: Vec<TrainSeed>,
}

impl<V: Copy, S: Copy> Plan<V, S> {
    /// A plan of `entries` × `seeds`.
    pub fn new(entries: Vec<(V, S)>, seeds: Vec<TrainSeed>) -> Self {
        Plan { entries, seeds }
    }

    /// One job per entry and seed, entry by entry.
    pub fn jobs(&self) -> Vec<Job<V, S>> {
        self.entries
            .iter()
            .flat_map(|&(variant, size)| {
                self.seeds.iter().map(move |&seed| Job {
                    variant,
                    size,
                    seed,
                })
            })
            .collect()
    }

    /// The results of [`Plan::jobs`] (in job order) back per entry.
    ///
    /// # Errors
    /// [`LearnError::Invalid`] if there are not exactly as many results as
    /// jobs.
    pub fn groups<R>(&self, results: Vec<R>) -> Result<Vec<Group<V, S, R>>> {
        let expected = self.entries.len() * self.seeds.len();
        if results.len() != expected {
            return Err(LearnError::invalid(
                "study results",
                format!("{} results for a plan of {expected} jobs", results.len()),
            ));
        }
        let mut results = results.into_iter();
        Ok(self
            .entries
            .iter()
            .map(|&(variant, size)| Group {
                variant,
                size,
                seeds: self.seeds.clone(),
                runs: results.by_ref().take(self.seeds.len()).collect(),
            })
            .collect())
    }
}

/// Runs `f` on every job on `threads` worker threads (at least one, at most
/// one per job) and returns the results in job order, or the error of the
/// first failed job in job order. Deterministic work gives the same results
/// whatever the thread count.
///
/// # Errors
/// The first error `f` returned, in job order.
pub fn run_jobs<J: Sync, R: Send, E: Send>(
    jobs: &[J],
    threads: usize,
    f: impl Fn(&J) -> std::result::Result<R, E> + Sync,
) -> std::result::Result<Vec<R>, E> {
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<std::result::Result<R, E>>>> =
        jobs.iter().map(|_| Mutex::new(None)).collect();
    std::thread::scope(|s| {
        for _ in 0..threads.clamp(1, jobs.len().max(1)) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= jobs.len() {
                    break;
                }
                let result = f(&jobs[i]);
                *slots[i].lock().unwrap_or_else(|e| e.into_inner()) = Some(result);
            });
        }
    });
    // The scope joined every worker and re-raised any panic, so every slot
    // holds its job's result.
    slots
        .into_iter()
        .map(|slot| {
            slot.into_inner()
                .unwrap_or_else(|e| e.into_inner())
                .expect("every job ran before the scope ended")
        })
        .collect()
}

/// Learning-rate pilots: every family trained at every rate (on a fraction of
/// the budget, as the caller decides), the rate of the lowest validation score
/// kept per family.
#[derive(Debug, Clone, PartialEq)]
pub struct Pilots<F> {
    /// The rate chosen for each family, in the order given.
    pub chosen: Vec<(F, f64)>,
    /// Every pilot's `(rate, validation score)`, per family; empty where
    /// there was nothing to pilot (one rate).
    pub scores: Vec<(F, Vec<(f64, f64)>)>,
}

impl<F: Copy + PartialEq> Pilots<F> {
    /// The rate chosen for `family`.
    pub fn rate(&self, family: F) -> Option<f64> {
        self.chosen.iter().find(|c| c.0 == family).map(|c| c.1)
    }
}

/// Chooses a learning rate per family on validation: `train(pilots)` trains
/// every `(family, rate)` pilot and returns their validation scores in the
/// same order; the lowest finite score wins (the first on ties). With a single
/// rate nothing is trained and every family takes it.
///
/// ```
/// use diffphys_learn::study::pilot_learning_rates;
///
/// // Validation scores of a stand-in training: family "b" prefers larger rates.
/// let pilots = pilot_learning_rates(&["a", "b"], &[1e-3, 1e-2], |jobs| {
///     Ok::<_, diffphys_learn::LearnError>(
///         jobs.iter().map(|&(f, lr)| if f == "a" { lr } else { 1.0 / lr }).collect(),
///     )
/// })?;
/// assert_eq!(pilots.rate("a"), Some(1e-3));
/// assert_eq!(pilots.rate("b"), Some(1e-2));
/// # Ok::<(), diffphys_learn::LearnError>(())
/// ```
///
/// # Errors
/// [`LearnError::Invalid`] without rates, or when `train` returns another
/// number of scores than pilots; [`LearnError::Selection`] when no pilot of a
/// family has a finite score; whatever `train` returns.
pub fn pilot_learning_rates<F, E>(
    families: &[F],
    rates: &[f64],
    train: impl FnOnce(&[(F, f64)]) -> std::result::Result<Vec<f64>, E>,
) -> std::result::Result<Pilots<F>, E>
where
    F: Copy + PartialEq + std::fmt::Debug,
    E: From<LearnError>,
{
    let (&first, more) = rates.split_first().ok_or_else(|| {
        LearnError::invalid("learning-rate pilots", "no learning rate to choose from")
    })?;
    if more.is_empty() {
        return Ok(Pilots {
            chosen: families.iter().map(|&f| (f, first)).collect(),
            scores: Vec::new(),
        });
    }
    let jobs: Vec<(F, f64)> = families
        .iter()
        .flat_map(|&f| rates.iter().map(move |&lr| (f, lr)))
        .collect();
    let scores = train(&jobs)?;
    if scores.len() != jobs.len() {
        return Err(LearnError::invalid(
            "learning-rate pilots",
            format!("{} scores for {} pilots", scores.len(), jobs.len()),
        )
        .into());
    }
    let mut out = Pilots {
        chosen: Vec::new(),
        scores: Vec::new(),
    };
    for (i, &family) in families.iter().enumerate() {
        let of: Vec<(f64, f64)> = rates
            .iter()
            .copied()
            .zip(
                scores[i * rates.len()..(i + 1) * rates.len()]
                    .iter()
                    .copied(),
            )
            .collect();
        let best = of
            .iter()
            .filter(|p| p.1.is_finite())
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .ok_or_else(|| LearnError::Selection {
                message: format!(
                    "no learning-rate pilot of {family:?} has a finite validation score"
                ),
            })?;
        out.chosen.push((family, best.0));
        out.scores.push((family, of));
    }
    Ok(out)
}

/// Selection on validation over a study's groups `(label, runs)`: the groups
/// that `compete` are the candidates of one choice (an unroll, a size), every
/// other group is a candidate on its own (nothing to choose, but released for
/// its one held-out evaluation the same way). A group's score is the mean of
/// `score` over its runs (its training seeds). The competing selection, if any
/// group competes, comes first; the others follow in the order given.
///
/// ```
/// use diffphys_learn::study::select_groups;
///
/// let groups = vec![("non", vec![0.5, 0.7]), ("sol4", vec![0.3, 0.5]), ("sol16", vec![0.2, 0.3])];
/// let selections = select_groups(groups, |l| l.starts_with("sol"), |&s| s)?;
/// assert_eq!(*selections[0].chosen_label(), "sol16");
/// assert_eq!(selections[0].models.len(), 2);
/// assert_eq!(*selections[1].chosen_label(), "non");
/// # Ok::<(), diffphys_learn::LearnError>(())
/// ```
///
/// # Errors
/// [`LearnError::Invalid`] for a group without runs; [`LearnError::Selection`]
/// when no competing group has a finite score.
pub fn select_groups<M, L>(
    groups: Vec<(L, Vec<M>)>,
    competes: impl Fn(&L) -> bool,
    score: impl Fn(&M) -> f64,
) -> Result<Vec<Selection<Vec<M>, L>>> {
    let mut competing = Vec::new();
    let mut alone = Vec::new();
    for (label, runs) in groups {
        if runs.is_empty() {
            return Err(LearnError::invalid(
                "study selection",
                "a group without trained runs",
            ));
        }
        let mean = runs.iter().map(&score).sum::<f64>() / runs.len() as f64;
        let joins = competes(&label);
        let candidate = Candidate::new(label, Trained::new(runs), mean);
        if joins {
            competing.push(candidate);
        } else {
            alone.push(candidate);
        }
    }
    let mut selections = Vec::new();
    if !competing.is_empty() {
        selections.push(select_best(competing)?);
    }
    for c in alone {
        selections.push(select_best(vec![c])?);
    }
    Ok(selections)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_come_back_in_job_order_whatever_the_thread_count() {
        let jobs: Vec<u64> = (0..23).collect();
        let square = |j: &u64| Ok::<_, ()>(j * j);
        let one = run_jobs(&jobs, 1, square).unwrap();
        for threads in [2, 5, 64] {
            assert_eq!(run_jobs(&jobs, threads, square).unwrap(), one);
        }
        assert_eq!(one[7], 49);
        assert!(run_jobs(&[] as &[u64], 4, square).unwrap().is_empty());
    }

    #[test]
    fn the_first_failure_in_job_order_is_returned() {
        let jobs: Vec<u64> = (0..10).collect();
        let r = run_jobs(&jobs, 3, |&j| if j % 4 == 3 { Err(j) } else { Ok(j) });
        assert_eq!(r, Err(3));
    }

    #[test]
    fn groups_need_one_result_per_job() {
        let plan = Plan::new(
            vec![("a", 1), ("b", 2)],
            vec![TrainSeed(1), TrainSeed(2), TrainSeed(3)],
        );
        assert_eq!(plan.jobs().len(), 6);
        assert_eq!(plan.jobs()[4].variant, "b");
        assert_eq!(plan.jobs()[4].seed, TrainSeed(2));
        let groups = plan.groups((0..6).collect()).unwrap();
        assert_eq!(groups[1].runs, vec![3, 4, 5]);
        assert!(matches!(
            plan.groups(vec![0; 5]),
            Err(LearnError::Invalid { .. })
        ));
    }

    #[test]
    fn pilots_train_nothing_for_one_rate_and_refuse_bad_scores() {
        let one = pilot_learning_rates(&["a"], &[1e-3], |_| -> Result<Vec<f64>> {
            panic!("nothing to pilot")
        })
        .unwrap();
        assert_eq!(one.rate("a"), Some(1e-3));
        assert!(one.scores.is_empty());
        let none = pilot_learning_rates(&["a"], &[], |_| Ok::<_, LearnError>(vec![]));
        assert!(matches!(none, Err(LearnError::Invalid { .. })));
        let short = pilot_learning_rates(&["a", "b"], &[1e-3, 1e-2], |_| {
            Ok::<_, LearnError>(vec![1.0; 3])
        });
        assert!(matches!(short, Err(LearnError::Invalid { .. })));
        // A NaN pilot is never chosen; a family with no finite pilot is refused.
        let nan = pilot_learning_rates(&["a", "b"], &[1e-3, 1e-2], |_| {
            Ok::<_, LearnError>(vec![f64::NAN, 2.0, f64::NAN, f64::INFINITY])
        });
        assert!(matches!(nan, Err(LearnError::Selection { .. })));
        let ok = pilot_learning_rates(&["a"], &[1e-3, 1e-2], |_| {
            Ok::<_, LearnError>(vec![f64::NAN, 2.0])
        })
        .unwrap();
        assert_eq!(ok.rate("a"), Some(1e-2));
    }

    #[test]
    fn group_selection_refuses_empty_groups_and_keeps_singles_in_order() {
        let empty = select_groups(vec![("a", Vec::<f64>::new())], |_| true, |&s| s);
        assert!(matches!(empty, Err(LearnError::Invalid { .. })));
        let s = select_groups(
            vec![("x", vec![1.0]), ("y", vec![2.0]), ("z", vec![0.5])],
            |_| false,
            |&v| v,
        )
        .unwrap();
        let labels: Vec<&str> = s.iter().map(|sel| *sel.chosen_label()).collect();
        assert_eq!(labels, ["x", "y", "z"]);
        let nan = select_groups(vec![("sol", vec![f64::NAN])], |_| true, |&v| v);
        assert!(matches!(nan, Err(LearnError::Selection { .. })));
    }
}
