//! The state a [`crate::Simulator`] advances: several fields of their own
//! shapes (a velocity component per face set, a pressure, a concentration) and
//! per-sample parameters (a viscosity, an inflow profile) that the solver and
//! the corrector read and nothing changes.
//!
//! A [`State`] is one sample (no batch axis) or a batch (axis 0 the batch in
//! every array); [`State::stack`] makes the second from the first and
//! [`State::sample`] goes back. On a tape the same state is a [`StateVars`].
//!
//! Which fields are physical: the simulator says how many of the last fields
//! are its own auxiliaries ([`crate::Simulator::auxiliary_fields`], such as a
//! pressure carried for incremental splitting). The physical fields are the
//! ones the losses and errors compare, the corrector corrects and the input
//! noise perturbs; auxiliaries are carried from step to step and compared with
//! nothing.

use diffphys_tape::{ArrayD, Tape, Var};
use ndarray::{ArrayViewD, Axis};

use crate::{LearnError, Result};

/// Fields and per-sample parameters: one sample, or a batch along axis 0 of
/// every array.
#[derive(Debug, Clone, PartialEq)]
pub struct State {
    /// The fields the solver advances, in the simulator's order (physical
    /// ones first, then its auxiliaries).
    pub fields: Vec<ArrayD<f64>>,
    /// Per-sample parameters: read by the solver and the corrector, never
    /// changed, compared, corrected or perturbed.
    pub params: Vec<ArrayD<f64>>,
}

impl From<ArrayD<f64>> for State {
    /// A state of one field and no parameters.
    fn from(field: ArrayD<f64>) -> Self {
        State {
            fields: vec![field],
            params: Vec::new(),
        }
    }
}

fn arrays(s: &State) -> impl Iterator<Item = &ArrayD<f64>> {
    s.fields.iter().chain(&s.params)
}

impl State {
    /// A state of `fields` with per-sample `params`.
    pub fn new(fields: Vec<ArrayD<f64>>, params: Vec<ArrayD<f64>>) -> Self {
        State { fields, params }
    }

    /// Stacks same-layout samples into a batch along a new axis 0 of every
    /// array.
    ///
    /// # Errors
    /// [`LearnError::Invalid`] without samples, or for samples whose numbers
    /// of fields or parameters, or whose arrays' shapes, differ.
    pub fn stack(samples: &[&State]) -> Result<State> {
        let first = samples
            .first()
            .ok_or_else(|| LearnError::invalid("batch", "no samples"))?;
        let layout = |s: &State| (s.fields.len(), s.params.len());
        if let Some(other) = samples.iter().find(|s| layout(s) != layout(first)) {
            return Err(LearnError::invalid(
                "batch",
                format!(
                    "a sample of {:?} (fields, parameters) beside one of {:?}",
                    layout(other),
                    layout(first)
                ),
            ));
        }
        let stack_at = |pick: &dyn Fn(&State) -> &ArrayD<f64>| {
            let views: Vec<ArrayViewD<'_, f64>> = samples.iter().map(|s| pick(s).view()).collect();
            ndarray::stack(Axis(0), &views).map_err(|e| LearnError::invalid("batch", e.to_string()))
        };
        let fields = (0..first.fields.len())
            .map(|f| stack_at(&|s: &State| &s.fields[f]))
            .collect::<Result<Vec<_>>>()?;
        let params = (0..first.params.len())
            .map(|p| stack_at(&|s: &State| &s.params[p]))
            .collect::<Result<Vec<_>>>()?;
        Ok(State { fields, params })
    }

    /// The samples in the batch: the length of axis 0 of the first field (0
    /// for a state without fields or a 0-d field).
    pub fn batch_len(&self) -> usize {
        self.fields
            .first()
            .and_then(|f| f.shape().first().copied())
            .unwrap_or(0)
    }

    /// Sample `b` of a batch.
    ///
    /// # Errors
    /// [`LearnError::Invalid`] if an array has no sample `b`.
    pub fn sample(&self, b: usize) -> Result<State> {
        let row = |a: &ArrayD<f64>| {
            if a.ndim() == 0 || a.shape()[0] <= b {
                return Err(LearnError::invalid(
                    "state",
                    format!("sample {b} asked of an array of shape {:?}", a.shape()),
                ));
            }
            Ok(a.index_axis(Axis(0), b).to_owned())
        };
        Ok(State {
            fields: self.fields.iter().map(row).collect::<Result<_>>()?,
            params: self.params.iter().map(row).collect::<Result<_>>()?,
        })
    }

    /// Whether every entry of every array is finite.
    pub fn is_finite(&self) -> bool {
        arrays(self).all(|a| a.iter().all(|x| x.is_finite()))
    }

    /// The state as constants of `tape`.
    pub fn constants<'t>(&self, tape: &'t Tape<f64>) -> StateVars<'t> {
        StateVars {
            fields: self
                .fields
                .iter()
                .map(|f| tape.constant(f.clone()))
                .collect(),
            params: self
                .params
                .iter()
                .map(|p| tape.constant(p.clone()))
                .collect(),
        }
    }

    /// The fields as variables of `tape` (gradients reach them), the
    /// parameters as its constants.
    pub fn variables<'t>(&self, tape: &'t Tape<f64>) -> StateVars<'t> {
        StateVars {
            fields: self.fields.iter().map(|f| tape.var(f.clone())).collect(),
            params: self
                .params
                .iter()
                .map(|p| tape.constant(p.clone()))
                .collect(),
        }
    }
}

/// A [`State`] on a tape.
#[derive(Debug, Clone)]
pub struct StateVars<'t> {
    /// The fields, in the simulator's order.
    pub fields: Vec<Var<'t, f64>>,
    /// The per-sample parameters.
    pub params: Vec<Var<'t, f64>>,
}

impl<'t> StateVars<'t> {
    /// The only field of a one-field state (a simulator written for one array
    /// calls this).
    ///
    /// # Errors
    /// [`diffphys_tape::TapeError::InvalidArgument`] for a state of another
    /// number of fields.
    pub fn only(&self) -> diffphys_tape::Result<Var<'t, f64>> {
        match self.fields.as_slice() {
            [f] => Ok(*f),
            other => Err(diffphys_tape::TapeError::invalid(
                "state",
                format!("one field expected, got {}", other.len()),
            )),
        }
    }

    /// The current values.
    pub fn to_state(&self) -> State {
        State {
            fields: self.fields.iter().map(Var::to_array).collect(),
            params: self.params.iter().map(Var::to_array).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(x: f64) -> State {
        State::new(
            vec![
                ArrayD::from_elem(vec![2, 3], x),
                ArrayD::from_elem(vec![4], -x),
            ],
            vec![ArrayD::from_elem(vec![1], 10.0 * x)],
        )
    }

    #[test]
    fn stack_and_sample_are_inverse() {
        let (a, b) = (sample(1.0), sample(2.0));
        let batch = State::stack(&[&a, &b]).unwrap();
        assert_eq!(batch.batch_len(), 2);
        assert_eq!(batch.fields[0].shape(), &[2, 2, 3]);
        assert_eq!(batch.fields[1].shape(), &[2, 4]);
        assert_eq!(batch.params[0].shape(), &[2, 1]);
        assert_eq!(batch.sample(0).unwrap(), a);
        assert_eq!(batch.sample(1).unwrap(), b);
        assert!(batch.sample(2).is_err());
    }

    #[test]
    fn samples_of_other_layouts_do_not_stack() {
        let a = sample(1.0);
        let mut b = sample(1.0);
        b.params.clear();
        assert!(matches!(
            State::stack(&[&a, &b]),
            Err(LearnError::Invalid { .. })
        ));
        let mut c = sample(1.0);
        c.fields[1] = ArrayD::zeros(vec![5]);
        assert!(matches!(
            State::stack(&[&a, &c]),
            Err(LearnError::Invalid { .. })
        ));
        assert!(matches!(State::stack(&[]), Err(LearnError::Invalid { .. })));
    }

    #[test]
    fn a_state_on_a_tape_comes_back_unchanged() {
        let tape = Tape::new();
        let s = sample(3.0);
        assert_eq!(s.constants(&tape).to_state(), s);
        assert!(s.variables(&tape).only().is_err());
        let one = State::from(ArrayD::zeros(vec![3]));
        assert_eq!(one.constants(&tape).only().unwrap().shape(), vec![3]);
        let mut bad = sample(1.0);
        assert!(bad.is_finite());
        bad.params[0][[0]] = f64::NAN;
        assert!(!bad.is_finite());
    }
}
