//! Data as types: three splits from separate seed streams of one data seed, and a
//! held-out split that is read once per trained model, after selection.
//!
//! A [`DataSeed`] derives one random stream per [`Split`]; drawing the training
//! set never moves the validation or held-out streams, so each split is the same
//! whatever the sizes of the others. [`Splits::generate`] draws all three.
//!
//! The held-out data sits inside [`HeldOut`], which has no accessor: the only way
//! to read it is [`HeldOut::evaluate`], which takes a [`Selected`] model by value.
//! A `Selected` comes only from [`select_best`], which reads validation scores
//! only, so the held-out split cannot be read before selection, and a selected
//! model cannot be evaluated twice (it is moved). [`HeldOut`] also remembers which
//! trained models it has seen ([`ModelId`]), so a clone of a trained model selected
//! again is refused at run time ([`crate::LearnError::HeldOutReused`]).
//!
//! The same calls the guarded ones below make, written correctly, compile and run:
//!
//! ```
//! # use diffphys_learn::{select_best, Candidate, DataSeed, Splits, Trained};
//! let splits = Splits::generate(DataSeed(1), [1, 1, 1], |_, n, _| Ok(vec![0.0; n]))?;
//! let mut selection = select_best(vec![Candidate::new("a", Trained::new(()), 1.0)])?;
//! let model = selection.models.remove(0);
//! let evaluated = splits.held_out().evaluate(model, |_, d| Ok(d.len()))?;
//! assert_eq!(evaluated.result, 1);
//! # Ok::<(), diffphys_learn::LearnError>(())
//! ```
//!
//! ```compile_fail,E0616
//! // The held-out data has no public field or accessor.
//! # use diffphys_learn::{DataSeed, Splits};
//! let splits = Splits::generate(DataSeed(1), [1, 1, 1], |_, n, _| Ok(vec![0.0; n])).unwrap();
//! let peek = &splits.held_out().data;
//! ```
//!
//! ```compile_fail,E0451
//! // A selected model cannot be made by hand.
//! # use diffphys_learn::Selected;
//! let s = Selected { id: 0, label: String::new(), model: (), validation: 0.0, chosen: true };
//! ```
//!
//! ```compile_fail,E0382
//! // A selected model is evaluated once: the second call uses a moved value.
//! # use diffphys_learn::{select_best, Candidate, DataSeed, Splits, Trained};
//! let splits = Splits::generate(DataSeed(1), [1, 1, 1], |_, n, _| Ok(vec![0.0; n])).unwrap();
//! let mut selection = select_best(vec![Candidate::new("a", Trained::new(()), 1.0)]).unwrap();
//! let model = selection.models.remove(0);
//! splits.held_out().evaluate(model, |_, _| Ok(1.0)).unwrap();
//! splits.held_out().evaluate(model, |_, _| Ok(1.0)).unwrap();
//! ```

use std::cell::{Cell, RefCell};
use std::collections::HashSet;
use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};

use rand::rngs::StdRng;
use rand::SeedableRng;

pub use crate::split::Split;
use crate::{LearnError, Result};

/// SplitMix64's finaliser: a bijective mix of 64 bits.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The seed of one draw of data: the training, validation and held-out splits
/// all derive from it, each in its own stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct DataSeed(pub u64);

impl DataSeed {
    /// The random stream of `split`: independent of the other splits' streams
    /// (different 64-bit seeds from a bijective mix of `(seed, split)`).
    pub fn rng(self, split: Split) -> StdRng {
        let tag = match split {
            Split::Train => 0x5452_4149_4E00_0001,
            Split::Validation => 0x5641_4C49_4400_0002,
            Split::HeldOut => 0x4845_4C44_4F55_0003,
        };
        StdRng::seed_from_u64(mix(mix(self.0) ^ tag))
    }
}

/// The seed of one training: the network's initialisation and the training's own
/// randomness (sampled windows, input noise) come from separate streams of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TrainSeed(pub u64);

impl TrainSeed {
    /// The stream of the network's initial parameters.
    pub fn init_rng(self) -> StdRng {
        StdRng::seed_from_u64(mix(mix(self.0) ^ 0x494E_4954_0000_0001))
    }

    /// The stream of the training's sampling (windows, noise).
    pub fn sampling_rng(self) -> StdRng {
        StdRng::seed_from_u64(mix(mix(self.0) ^ 0x5341_4D50_0000_0002))
    }
}

/// Identifies one trained model (unique within the process; clones share it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ModelId(u64);

impl ModelId {
    fn fresh() -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(1);
        ModelId(NEXT.fetch_add(1, Ordering::Relaxed))
    }

    /// The number.
    pub fn get(self) -> u64 {
        self.0
    }
}

/// A trained model with its identity. Cloning keeps the identity, so the
/// held-out guard recognises the same model however often it is cloned.
#[derive(Debug, Clone)]
pub struct Trained<M> {
    id: ModelId,
    /// The model (parameters, or whatever the trainer produced).
    pub model: M,
}

impl<M> Trained<M> {
    /// A newly trained model with a fresh identity.
    pub fn new(model: M) -> Self {
        Trained {
            id: ModelId::fresh(),
            model,
        }
    }

    /// Its identity.
    pub fn id(&self) -> ModelId {
        self.id
    }
}

/// A trained model and its validation score (lower is better), offered to
/// [`select_best`]. Its label `L` is whatever names a candidate in the study:
/// a string, or a typed variant (`Variant::Sol(4)` at a size) that selection
/// hands back as it was given, so nothing has to be parsed out of a name.
#[derive(Debug, Clone)]
pub struct Candidate<M, L = String> {
    label: L,
    trained: Trained<M>,
    validation: f64,
}

impl<M, L> Candidate<M, L> {
    /// `trained`, labelled, with its score on the validation split.
    pub fn new(label: L, trained: Trained<M>, validation: f64) -> Self {
        Candidate {
            label,
            trained,
            validation,
        }
    }
}

/// A model released for its one held-out evaluation by [`select_best`].
#[derive(Debug)]
pub struct Selected<M, L = String> {
    id: ModelId,
    label: L,
    model: M,
    validation: f64,
    chosen: bool,
}

impl<M, L> Selected<M, L> {
    /// The candidate's label.
    pub fn label(&self) -> &L {
        &self.label
    }
    /// Its validation score.
    pub fn validation(&self) -> f64 {
        self.validation
    }
    /// Whether validation chose it.
    pub fn chosen(&self) -> bool {
        self.chosen
    }
    /// The model (for validation-side uses such as charts of training curves).
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The model released without its held-out evaluation (a run that
    /// develops on validation only): the held-out split is not read, and the
    /// result is `()`.
    pub fn withhold(self) -> Evaluated<M, (), L> {
        Evaluated {
            label: self.label,
            chosen: self.chosen,
            validation: self.validation,
            model: self.model,
            result: (),
        }
    }
}

/// The outcome of [`select_best`]: which candidate validation chose, and every
/// candidate released for its one held-out evaluation.
#[derive(Debug)]
pub struct Selection<M, L = String> {
    /// The index of the chosen candidate in `models`.
    pub chosen: usize,
    /// Every candidate, in the order given.
    pub models: Vec<Selected<M, L>>,
}

impl<M, L> Selection<M, L> {
    /// The chosen candidate's label.
    pub fn chosen_label(&self) -> &L {
        &self.models[self.chosen].label
    }
}

/// Chooses the candidate with the lowest validation score (the first on ties).
/// Reads nothing but the validation scores.
///
/// # Errors
/// [`LearnError::Selection`] without candidates or when no score is finite.
pub fn select_best<M, L>(candidates: Vec<Candidate<M, L>>) -> Result<Selection<M, L>> {
    let chosen = candidates
        .iter()
        .enumerate()
        .filter(|(_, c)| c.validation.is_finite())
        .min_by(|a, b| a.1.validation.total_cmp(&b.1.validation))
        .map(|(i, _)| i)
        .ok_or_else(|| LearnError::Selection {
            message: format!(
                "no candidate with a finite validation score among {}",
                candidates.len()
            ),
        })?;
    let models = candidates
        .into_iter()
        .enumerate()
        .map(|(i, c)| Selected {
            id: c.trained.id,
            label: c.label,
            model: c.trained.model,
            validation: c.validation,
            chosen: i == chosen,
        })
        .collect();
    Ok(Selection { chosen, models })
}

/// A held-out evaluation's result, with the model it came from.
#[derive(Debug)]
pub struct Evaluated<M, R, L = String> {
    /// The candidate's label.
    pub label: L,
    /// Whether validation chose it.
    pub chosen: bool,
    /// Its validation score.
    pub validation: f64,
    /// The model.
    pub model: M,
    /// What the evaluation returned.
    pub result: R,
}

/// The held-out split: sealed, readable only through [`HeldOut::evaluate`]
/// (once per trained model) and [`HeldOut::evaluate_baseline`] (models without
/// trained parameters), and counting every reading ([`HeldOut::readings`]) so
/// that a report can say how often the split was read.
#[derive(Debug)]
pub struct HeldOut<D> {
    data: D,
    seen: RefCell<HashSet<ModelId>>,
    baseline_readings: Cell<usize>,
}

impl<D> HeldOut<D> {
    fn sealed(data: D) -> Self {
        HeldOut {
            data,
            seen: RefCell::new(HashSet::new()),
            baseline_readings: Cell::new(0),
        }
    }

    /// How often the split was read: `(trained models evaluated, baseline
    /// readings)`. A trained model is evaluated at most once.
    pub fn readings(&self) -> (usize, usize) {
        (self.seen.borrow().len(), self.baseline_readings.get())
    }

    /// Runs `f` on the selected model and the held-out data, once per trained
    /// model.
    ///
    /// # Errors
    /// [`LearnError::HeldOutReused`] if this model (or a clone of it) was
    /// evaluated here before; whatever `f` returns.
    pub fn evaluate<M, R, L: fmt::Display>(
        &self,
        selected: Selected<M, L>,
        f: impl FnOnce(&M, &D) -> Result<R>,
    ) -> Result<Evaluated<M, R, L>> {
        if !self.seen.borrow_mut().insert(selected.id) {
            return Err(LearnError::HeldOutReused {
                model: selected.id.0,
                label: selected.label.to_string(),
            });
        }
        let result = f(&selected.model, &self.data)?;
        Ok(Evaluated {
            label: selected.label,
            chosen: selected.chosen,
            validation: selected.validation,
            model: selected.model,
            result,
        })
    }

    /// Runs `f` on the held-out data for a baseline that has no trained
    /// parameters (the uncorrected solver, the zero guess): nothing to select,
    /// nothing to guard.
    ///
    /// # Errors
    /// Whatever `f` returns.
    pub fn evaluate_baseline<R>(&self, f: impl FnOnce(&D) -> Result<R>) -> Result<R> {
        self.baseline_readings.set(self.baseline_readings.get() + 1);
        f(&self.data)
    }
}

/// The three splits of one [`DataSeed`].
#[derive(Debug)]
pub struct Splits<D> {
    /// The seed they came from.
    pub seed: DataSeed,
    /// The training split.
    pub train: D,
    /// The validation split.
    pub validation: D,
    held_out: HeldOut<D>,
}

impl<D> Splits<D> {
    /// Draws `sizes = [train, validation, held_out]` samples, each split from its
    /// own stream of `seed`: `draw(split, count, rng)`.
    ///
    /// # Errors
    /// [`LearnError::EmptySplit`] if a size is zero; whatever `draw` returns.
    pub fn generate(
        seed: DataSeed,
        sizes: [usize; 3],
        mut draw: impl FnMut(Split, usize, &mut StdRng) -> Result<D>,
    ) -> Result<Self> {
        let splits = [Split::Train, Split::Validation, Split::HeldOut];
        for (split, &n) in splits.iter().zip(&sizes) {
            if n == 0 {
                return Err(LearnError::EmptySplit {
                    split: *split,
                    context: format!("data seed {}", seed.0),
                });
            }
        }
        let mut out = splits
            .iter()
            .zip(sizes)
            .map(|(&split, n)| draw(split, n, &mut seed.rng(split)));
        let (train, validation, held_out) = (
            out.next().expect("three")?,
            out.next().expect("three")?,
            out.next().expect("three")?,
        );
        Ok(Splits {
            seed,
            train,
            validation,
            held_out: HeldOut::sealed(held_out),
        })
    }

    /// The held-out split, behind its guard.
    pub fn held_out(&self) -> &HeldOut<D> {
        &self.held_out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    #[test]
    fn streams_differ_per_split_and_repeat_per_seed() {
        let draw = |seed: u64, split| DataSeed(seed).rng(split).random::<u64>();
        assert_ne!(draw(1, Split::Train), draw(1, Split::Validation));
        assert_ne!(draw(1, Split::Validation), draw(1, Split::HeldOut));
        assert_ne!(draw(1, Split::Train), draw(2, Split::Train));
        assert_eq!(draw(7, Split::HeldOut), draw(7, Split::HeldOut));
        assert_ne!(
            TrainSeed(3).init_rng().random::<u64>(),
            TrainSeed(3).sampling_rng().random::<u64>()
        );
    }

    #[test]
    fn a_split_does_not_depend_on_the_others_sizes() {
        let draw = |_: Split, n: usize, rng: &mut StdRng| -> Result<Vec<u64>> {
            Ok((0..n).map(|_| rng.random()).collect())
        };
        let a = Splits::generate(DataSeed(5), [3, 2, 4], draw).unwrap();
        let b = Splits::generate(DataSeed(5), [10, 2, 1], draw).unwrap();
        assert_eq!(a.validation, b.validation);
        assert_eq!(a.train[..3], b.train[..3]);
    }

    #[test]
    fn an_empty_split_is_an_error() {
        let draw = |_: Split, n: usize, _: &mut StdRng| -> Result<Vec<u8>> { Ok(vec![0; n]) };
        for (sizes, split) in [
            ([0, 1, 1], Split::Train),
            ([1, 0, 1], Split::Validation),
            ([1, 1, 0], Split::HeldOut),
        ] {
            match Splits::generate(DataSeed(1), sizes, draw) {
                Err(LearnError::EmptySplit { split: s, .. }) => assert_eq!(s, split),
                other => panic!("expected an empty-split error, got {other:?}"),
            }
        }
    }

    #[test]
    fn selection_reads_validation_and_held_out_is_read_once_per_model() {
        let draw = |_: Split, n: usize, _: &mut StdRng| -> Result<Vec<f64>> { Ok(vec![2.0; n]) };
        let splits = Splits::generate(DataSeed(1), [1, 1, 3], draw).unwrap();
        let a = Trained::new(10.0);
        let b = Trained::new(20.0);
        let a_again = a.clone();
        let selection = select_best(vec![
            Candidate::new("a", a, 0.5),
            Candidate::new("b", b, 0.25),
        ])
        .unwrap();
        assert_eq!(selection.chosen, 1);
        assert_eq!(*selection.chosen_label(), "b");
        for model in selection.models {
            let e = splits
                .held_out()
                .evaluate(model, |m, d| Ok(m * d.len() as f64))
                .unwrap();
            assert_eq!(e.result, e.model * 3.0);
        }
        // A clone of a model already evaluated, selected again, is refused.
        let again = select_best(vec![Candidate::new("a", a_again, 0.5)]).unwrap();
        let model = again.models.into_iter().next().unwrap();
        match splits.held_out().evaluate(model, |m, _| Ok(*m)) {
            Err(LearnError::HeldOutReused { label, .. }) => assert_eq!(label, "a"),
            other => panic!("expected the held-out guard, got {other:?}"),
        }
    }

    #[test]
    fn selection_without_finite_scores_is_an_error() {
        assert!(matches!(
            select_best::<(), String>(vec![]),
            Err(LearnError::Selection { .. })
        ));
        assert!(matches!(
            select_best(vec![Candidate::new("nan", Trained::new(()), f64::NAN)]),
            Err(LearnError::Selection { .. })
        ));
    }
}
