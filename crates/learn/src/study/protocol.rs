//! The protocol of one data seed, in one place: train every job of a plan,
//! select on validation, evaluate each trained model once on the held-out
//! split.

use std::fmt;

use super::{run_jobs, select_groups, Job, Plan};
use crate::data::{Evaluated, HeldOut, Selection, TrainSeed};
use crate::LearnError;

/// A `(variant, size)` of a plan: the typed label selection hands back,
/// printed `variant@size` (`variant` alone for [`OneSize`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Entry<V, S> {
    /// The variant (how it is trained).
    pub variant: V,
    /// The model's size.
    pub size: S,
}

impl<V: fmt::Display, S: fmt::Display> fmt::Display for Entry<V, S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let size = self.size.to_string();
        if size.is_empty() {
            write!(f, "{}", self.variant)
        } else {
            write!(f, "{}@{size}", self.variant)
        }
    }
}

/// The size of a plan whose models all have one size (it prints as
/// nothing).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct OneSize;

impl fmt::Display for OneSize {
    fn fmt(&self, _: &mut fmt::Formatter<'_>) -> fmt::Result {
        Ok(())
    }
}

/// The selection of a plan's entries: each entry's trained models.
type EntrySelection<V, S, M> = Selection<Vec<M>, Entry<V, S>>;

/// One training of an [`Outcome`]: its seed, the trained model and its
/// held-out result.
#[derive(Debug, Clone)]
pub struct Run<M, R> {
    /// The training seed.
    pub seed: TrainSeed,
    /// The trained model.
    pub model: M,
    /// What its one held-out evaluation returned.
    pub held_out: R,
}

/// A `(variant, size)` of the plan after the protocol.
#[derive(Debug, Clone)]
pub struct Outcome<V, S, M, R> {
    /// The entry.
    pub entry: Entry<V, S>,
    /// Whether it competed with others for one choice (an unroll, a size).
    pub competed: bool,
    /// Whether validation chose it: among the competing entries, the one of
    /// the lowest mean validation score; an entry that did not compete is
    /// always chosen (it had nothing to be chosen against).
    pub chosen: bool,
    /// The mean validation score over its trainings.
    pub validation: f64,
    /// Its trainings, in the plan's seed order.
    pub runs: Vec<Run<M, R>>,
}

impl<V, S, M, R> Outcome<V, S, M, R> {
    /// Whether validation chose it among competing entries (the selected
    /// unroll, say).
    pub fn selected(&self) -> bool {
        self.competed && self.chosen
    }

    /// The same outcome with `f` applied to each run's held-out result (a
    /// scene that runs both [`Protocol::run`] and [`Protocol::select`] holds
    /// their outcomes as one type, say `Option<R>`).
    pub fn map_held_out<Q>(self, mut f: impl FnMut(R) -> Q) -> Outcome<V, S, M, Q> {
        Outcome {
            entry: self.entry,
            competed: self.competed,
            chosen: self.chosen,
            validation: self.validation,
            runs: self
                .runs
                .into_iter()
                .map(|r| Run {
                    seed: r.seed,
                    model: r.model,
                    held_out: f(r.held_out),
                })
                .collect(),
        }
    }
}

/// The protocol of one data seed: every job of `plan` trained on `threads`
/// workers, the entries selected on validation, each trained model evaluated
/// once on the held-out split.
///
/// ```
/// use diffphys_learn::study::{OneSize, Plan, Protocol};
/// use diffphys_learn::{DataSeed, LearnError, Splits, TrainSeed};
///
/// // A stand-in scene: a "model" is its variant plus its seed; validation
/// // and the held-out figure are the model itself.
/// let splits = Splits::generate(DataSeed(1), [1, 1, 1], |_, _, _| Ok(vec![0.0]))?;
/// let plan = Plan::new(vec![(1u8, OneSize), (2, OneSize), (3, OneSize)], vec![TrainSeed(0), TrainSeed(1)]);
/// let outcomes = Protocol { plan: &plan, threads: 2 }.run(
///     splits.held_out(),
///     |job| Ok::<_, LearnError>(f64::from(job.variant) + job.seed.0 as f64 / 10.0),
///     |&m| m,
///     |e| e.variant > 1,
///     |_, models, data| Ok(models.iter().map(|m| m + data[0]).collect()),
/// )?;
/// // The competing entries (2 and 3) come first; 2 has the lower validation.
/// assert!(outcomes[0].selected() && outcomes[0].entry.variant == 2);
/// assert_eq!(outcomes[2].entry.variant, 1);
/// assert_eq!(outcomes[2].runs[1].held_out, 1.1);
/// assert_eq!(splits.held_out().readings(), (3, 0));
/// # Ok::<(), LearnError>(())
/// ```
#[derive(Debug, Clone, Copy)]
pub struct Protocol<'p, V, S> {
    /// What is trained.
    pub plan: &'p Plan<V, S>,
    /// Worker threads for the trainings.
    pub threads: usize,
}

impl<V, S> Protocol<'_, V, S>
where
    V: Copy + PartialEq + fmt::Display + Sync,
    S: Copy + PartialEq + fmt::Display + Sync,
{
    /// Runs the protocol:
    ///
    /// 1. `train(job)` for every job of the plan, on the workers (each
    ///    training deterministic for its seed, so the scheduling changes
    ///    nothing);
    /// 2. selection on validation only ([`select_groups`]): the entries that
    ///    `compete` are the candidates of one choice, scored by the mean of
    ///    `validation` over their trainings; every other entry stands alone;
    /// 3. the held-out split, once per trained model, after selection:
    ///    `evaluate(entry, models, data)` returns one result per model of the
    ///    entry, in order.
    ///
    /// The outcomes come in selection order: the competing entries first,
    /// then the others, each in the plan's order.
    ///
    /// # Errors
    /// The first error of `train` (in job order) or of `evaluate`;
    /// [`LearnError::Selection`] when no competing entry has a finite score;
    /// [`LearnError::Invalid`] when `evaluate` returns another number of
    /// results than models.
    pub fn run<D, M, R, E>(
        &self,
        held_out: &HeldOut<D>,
        train: impl Fn(&Job<V, S>) -> Result<M, E> + Sync,
        validation: impl Fn(&M) -> f64,
        competes: impl Fn(&Entry<V, S>) -> bool,
        mut evaluate: impl FnMut(&Entry<V, S>, &[M], &D) -> Result<Vec<R>, E>,
    ) -> Result<Vec<Outcome<V, S, M, R>>, E>
    where
        M: Send,
        E: From<LearnError> + Send,
    {
        let mut outcomes = Vec::new();
        for selection in self.train_and_select(train, validation, &competes)? {
            for selected in selection.models {
                let entry = *selected.label();
                let mut failure = None;
                let evaluated = held_out.evaluate(selected, |models, data| {
                    evaluate(&entry, models, data).map_err(|e| {
                        failure = Some(e);
                        LearnError::invalid("held-out evaluation", format!("{entry} failed"))
                    })
                });
                let evaluated = match (evaluated, failure) {
                    (_, Some(e)) => return Err(e),
                    (result, None) => result?,
                };
                if evaluated.result.len() != evaluated.model.len() {
                    return Err(LearnError::invalid(
                        "held-out evaluation",
                        format!(
                            "{} results for the {} models of {entry}",
                            evaluated.result.len(),
                            evaluated.model.len()
                        ),
                    )
                    .into());
                }
                outcomes.push(self.outcome(competes(&entry), evaluated));
            }
        }
        Ok(outcomes)
    }

    /// Steps 1 and 2 of [`Protocol::run`] without step 3: every job trained,
    /// the entries selected on validation, and the held-out split not read
    /// (a run that develops on validation only; each run's result is `()`).
    ///
    /// # Errors
    /// As [`Protocol::run`]'s training and selection.
    pub fn select<M, E>(
        &self,
        train: impl Fn(&Job<V, S>) -> Result<M, E> + Sync,
        validation: impl Fn(&M) -> f64,
        competes: impl Fn(&Entry<V, S>) -> bool,
    ) -> Result<Vec<Outcome<V, S, M, ()>>, E>
    where
        M: Send,
        E: From<LearnError> + Send,
    {
        let selections = self.train_and_select(train, validation, &competes)?;
        Ok(selections
            .into_iter()
            .flat_map(|s| s.models)
            .map(|selected| {
                let competed = competes(selected.label());
                let withheld = selected.withhold();
                let n = withheld.model.len();
                let evaluated = Evaluated {
                    result: vec![(); n],
                    label: withheld.label,
                    chosen: withheld.chosen,
                    validation: withheld.validation,
                    model: withheld.model,
                };
                self.outcome(competed, evaluated)
            })
            .collect())
    }

    /// Every job of the plan trained, grouped per entry and selected on
    /// validation.
    fn train_and_select<M, E>(
        &self,
        train: impl Fn(&Job<V, S>) -> Result<M, E> + Sync,
        validation: impl Fn(&M) -> f64,
        competes: &impl Fn(&Entry<V, S>) -> bool,
    ) -> Result<Vec<EntrySelection<V, S, M>>, E>
    where
        M: Send,
        E: From<LearnError> + Send,
    {
        let trained = run_jobs(&self.plan.jobs(), self.threads, train)?;
        let groups = self
            .plan
            .groups(trained)?
            .into_iter()
            .map(|g| {
                let entry = Entry {
                    variant: g.variant,
                    size: g.size,
                };
                (entry, g.runs)
            })
            .collect();
        Ok(select_groups(groups, competes, &validation)?)
    }

    /// The outcome of one entry: its models beside their results, in the
    /// plan's seed order.
    fn outcome<M, R>(
        &self,
        competed: bool,
        evaluated: Evaluated<Vec<M>, Vec<R>, Entry<V, S>>,
    ) -> Outcome<V, S, M, R> {
        Outcome {
            entry: evaluated.label,
            competed,
            chosen: evaluated.chosen,
            validation: evaluated.validation,
            runs: self
                .plan
                .seeds
                .iter()
                .zip(evaluated.model)
                .zip(evaluated.result)
                .map(|((&seed, model), held_out)| Run {
                    seed,
                    model,
                    held_out,
                })
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{DataSeed, Splits};

    fn splits() -> Splits<Vec<f64>> {
        Splits::generate(DataSeed(3), [1, 1, 1], |_, _, _| Ok(vec![0.5])).unwrap()
    }

    #[test]
    fn the_scene_error_of_a_failed_evaluation_comes_back_and_counts_are_checked() {
        #[derive(Debug, PartialEq)]
        enum SceneError {
            Learn,
            Diverged(u8),
        }
        impl From<LearnError> for SceneError {
            fn from(_: LearnError) -> Self {
                SceneError::Learn
            }
        }
        let plan = Plan::new(vec![(1u8, OneSize), (2, OneSize)], vec![TrainSeed(0)]);
        let protocol = Protocol {
            plan: &plan,
            threads: 1,
        };
        let s = splits();
        let failed = protocol.run(
            s.held_out(),
            |job| Ok(f64::from(job.variant)),
            |&m| m,
            |_| false,
            |e, _, _| Err::<Vec<f64>, _>(SceneError::Diverged(e.variant)),
        );
        assert_eq!(failed.unwrap_err(), SceneError::Diverged(1));
        let s = splits();
        let short = protocol.run(
            s.held_out(),
            |job| Ok::<_, SceneError>(f64::from(job.variant)),
            |&m| m,
            |_| false,
            |_, _, _| Ok(Vec::<f64>::new()),
        );
        assert_eq!(short.unwrap_err(), SceneError::Learn);
        let s = splits();
        let trained = protocol.run(
            s.held_out(),
            |job| {
                if job.variant == 2 {
                    Err(SceneError::Diverged(2))
                } else {
                    Ok(1.0)
                }
            },
            |&m| m,
            |_| false,
            |_, m, _| Ok(m.to_vec()),
        );
        assert_eq!(trained.unwrap_err(), SceneError::Diverged(2));
        // Nothing was read: training failed before selection.
        assert_eq!(s.held_out().readings(), (0, 0));
    }

    #[test]
    fn every_model_is_read_once_and_the_outcome_keeps_seed_order() {
        let plan = Plan::new(
            vec![("non", 8), ("sol4", 8), ("sol4", 16)],
            vec![TrainSeed(5), TrainSeed(6)],
        );
        let s = splits();
        let outcomes = Protocol {
            plan: &plan,
            threads: 3,
        }
        .run(
            s.held_out(),
            |job| Ok::<_, LearnError>((job.size as f64) + job.seed.0 as f64),
            |&m| 1.0 / m,
            |e| e.variant.starts_with("sol"),
            |_, models, data| Ok(models.iter().map(|m| m * data[0]).collect()),
        )
        .unwrap();
        let labels: Vec<String> = outcomes.iter().map(|o| o.entry.to_string()).collect();
        assert_eq!(labels, ["sol4@8", "sol4@16", "non@8"]);
        assert!(!outcomes[0].selected() && outcomes[1].selected());
        assert!(outcomes[2].chosen && !outcomes[2].selected());
        let seeds: Vec<u64> = outcomes[1].runs.iter().map(|r| r.seed.0).collect();
        assert_eq!(seeds, [5, 6]);
        assert_eq!(outcomes[1].runs[1].held_out, 11.0);
        assert_eq!(s.held_out().readings(), (3, 0));
    }

    #[test]
    fn selection_alone_reads_nothing_and_chooses_as_the_full_protocol() {
        let plan = Plan::new(
            vec![("non", 8), ("sol4", 8), ("sol4", 16)],
            vec![TrainSeed(5), TrainSeed(6)],
        );
        let protocol = Protocol {
            plan: &plan,
            threads: 2,
        };
        let train =
            |job: &Job<&str, i32>| Ok::<_, LearnError>((job.size as f64) + job.seed.0 as f64);
        let competes = |e: &Entry<&str, i32>| e.variant.starts_with("sol");
        let s = splits();
        let full = protocol
            .run(
                s.held_out(),
                train,
                |&m| 1.0 / m,
                competes,
                |_, m, _| Ok(m.to_vec()),
            )
            .unwrap();
        let alone = protocol.select(train, |&m| 1.0 / m, competes).unwrap();
        fn summary<R>(o: &[Outcome<&str, i32, f64, R>]) -> Vec<(String, bool, Vec<f64>)> {
            o.iter()
                .map(|o| {
                    let models = o.runs.iter().map(|r| r.model).collect();
                    (o.entry.to_string(), o.selected(), models)
                })
                .collect()
        }
        assert_eq!(summary(&alone), summary(&full));
        let s = splits();
        protocol.select(train, |&m| 1.0 / m, competes).unwrap();
        assert_eq!(s.held_out().readings(), (0, 0));
    }
}
