//! Studies: a plan of variants × sizes × training seeds, trained several at
//! once, grouped back per variant for selection on validation.
//!
//! A scene states its plan as values ([`Plan`]); [`Plan::jobs`] lists one
//! [`Job`] per training, [`run_jobs`] runs them on worker threads (each
//! training is deterministic for its seed, so the results do not depend on the
//! scheduling and come back in job order), and [`Plan::groups`] gives the
//! results back per `(variant, size)` with their training seeds, ready to be
//! made [`Candidate`](crate::Candidate)s labelled by the typed `(variant, size)`
//! itself.
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

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use crate::data::TrainSeed;
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
}
