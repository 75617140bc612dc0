//! Parameters: named arrays that a model owns and binds to a fresh tape for each
//! training step, with seeded initialisation and `.npz` save and load.

use std::path::Path;

use diffphys_tape::{ArrayD, Gradients, IxDyn, Optimizer, Real, Tape, Var};
use ndarray_npy::{NpzReader, NpzWriter, ReadableElement, WritableElement};
use rand::Rng;

use crate::{NnError, Result};

/// The scalars a network can be stored in: [`Real`] with `.npy` element support.
pub trait Scalar: Real + ReadableElement + WritableElement {}
impl<T: Real + ReadableElement + WritableElement> Scalar for T {}

/// How a weight array is initialised: uniform on `[−a, a]` with `a` from the
/// layer's fan-in and fan-out (so the variance is `a²/3`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Init {
    /// He (Kaiming) uniform, `a = √(6 / fan_in)`: variance `2 / fan_in`, for
    /// weights followed by ReLU.
    He,
    /// Glorot (Xavier) uniform, `a = √(6 / (fan_in + fan_out))`, for weights
    /// followed by tanh or nothing.
    Glorot,
    /// All zeros (biases).
    Zeros,
}

impl Init {
    /// A seeded array of `shape` with the given fans.
    pub fn sample<T: Real>(
        self,
        shape: &[usize],
        fan_in: usize,
        fan_out: usize,
        rng: &mut impl Rng,
    ) -> ArrayD<T> {
        let a = match self {
            Init::He => (6.0 / fan_in.max(1) as f64).sqrt(),
            Init::Glorot => (6.0 / (fan_in + fan_out).max(1) as f64).sqrt(),
            Init::Zeros => return ArrayD::zeros(IxDyn(shape)),
        };
        ArrayD::from_shape_simple_fn(IxDyn(shape), || T::from_f64(rng.random_range(-a..a)))
    }
}

/// The handle of one parameter in its [`Params`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ParamId(usize);

impl ParamId {
    /// Its position in [`Params`] (the order parameters were added).
    pub fn index(self) -> usize {
        self.0
    }
}

/// A model's parameters: named arrays in the order they were added.
///
/// Parameters live outside any tape. Each training step records on a new tape:
/// [`Params::bind`] turns every parameter into a variable of that tape, layers read
/// them through the returned [`Bound`], and [`Params::step`] applies an optimizer
/// to the gradients of the sweep.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Params<T: Real> {
    names: Vec<String>,
    values: Vec<ArrayD<T>>,
}

impl<T: Scalar> Params<T> {
    /// No parameters.
    pub fn new() -> Self {
        Params {
            names: Vec::new(),
            values: Vec::new(),
        }
    }

    /// Adds a parameter.
    ///
    /// # Errors
    /// [`NnError::DuplicateName`] if `name` is taken.
    pub fn add(&mut self, name: impl Into<String>, value: ArrayD<T>) -> Result<ParamId> {
        let name = name.into();
        if self.names.contains(&name) {
            return Err(NnError::DuplicateName { name });
        }
        self.names.push(name);
        self.values.push(value);
        Ok(ParamId(self.values.len() - 1))
    }

    /// Adds a parameter of `shape` drawn by `init` with the given fans.
    ///
    /// # Errors
    /// [`NnError::DuplicateName`] if `name` is taken.
    pub fn add_init(
        &mut self,
        name: impl Into<String>,
        shape: &[usize],
        init: Init,
        (fan_in, fan_out): (usize, usize),
        rng: &mut impl Rng,
    ) -> Result<ParamId> {
        self.add(name, init.sample(shape, fan_in, fan_out, rng))
    }

    /// The number of parameter arrays.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// The number of scalars over all parameters.
    pub fn count(&self) -> usize {
        self.values.iter().map(|v| v.len()).sum()
    }

    /// The names, in order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The values, in order.
    pub fn values(&self) -> &[ArrayD<T>] {
        &self.values
    }

    /// The value of one parameter.
    pub fn get(&self, id: ParamId) -> &ArrayD<T> {
        &self.values[id.0]
    }

    /// Every parameter as a variable of `tape`, for one forward and backward pass.
    pub fn bind<'t>(&self, tape: &'t Tape<T>) -> Bound<'t, T> {
        Bound {
            vars: self.values.iter().map(|v| tape.var(v.clone())).collect(),
        }
    }

    /// Every parameter as a constant of `tape`: a network that runs but does not
    /// train (a pretrained corrector inside a solver loop, say). No gradient
    /// reaches these values and the nodes that read only them and other
    /// constants are not recorded; do not pass the result to [`Params::step`].
    pub fn bind_frozen<'t>(&self, tape: &'t Tape<T>) -> Bound<'t, T> {
        Bound {
            vars: self
                .values
                .iter()
                .map(|v| tape.constant(v.clone()))
                .collect(),
        }
    }

    /// One optimizer step from the gradients of a sweep that requested
    /// `bound.vars()`.
    ///
    /// # Errors
    /// As [`Optimizer::step_vars`]: a missing or non-finite gradient changes
    /// nothing.
    pub fn step(
        &mut self,
        optimizer: &mut impl Optimizer<T>,
        grads: &Gradients<T>,
        bound: &Bound<'_, T>,
    ) -> Result<()> {
        optimizer.step_vars(&mut self.values, grads, &bound.vars)?;
        Ok(())
    }

    /// The square root of the sum of squares of all gradients of `bound` (zero
    /// where a parameter got none).
    pub fn grad_norm(grads: &Gradients<T>, bound: &Bound<'_, T>) -> f64 {
        bound
            .vars
            .iter()
            .filter_map(|v| grads.get(*v))
            .flat_map(|g| g.iter())
            .map(|g| g.as_f64() * g.as_f64())
            .sum::<f64>()
            .sqrt()
    }

    fn check_finite(&self) -> Result<()> {
        for (name, v) in self.names.iter().zip(&self.values) {
            let count = v.iter().filter(|x| !x.is_finite()).count();
            if count > 0 {
                return Err(NnError::NonFiniteParameter {
                    name: name.clone(),
                    count,
                });
            }
        }
        Ok(())
    }

    /// Writes every parameter to an uncompressed `.npz` file (one `.npy` array per
    /// name, readable by `numpy.load`). Values round-trip bit for bit.
    ///
    /// # Errors
    /// [`NnError::NonFiniteParameter`] (nothing is written) or [`NnError::File`].
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        self.check_finite()?;
        let file_error = |message: String| NnError::File {
            path: path.to_path_buf(),
            message,
        };
        let file = std::fs::File::create(path).map_err(|e| file_error(e.to_string()))?;
        let mut npz = NpzWriter::new(file);
        for (name, v) in self.names.iter().zip(&self.values) {
            npz.add_array(name.as_str(), v)
                .map_err(|e| file_error(format!("writing {name:?}: {e}")))?;
        }
        npz.finish().map_err(|e| file_error(e.to_string()))?;
        Ok(())
    }

    /// Replaces every parameter with the array of the same name in a `.npz` file
    /// written by [`Params::save`] (or NumPy's `savez`).
    ///
    /// # Errors
    /// [`NnError::File`] if the file cannot be read; [`NnError::Mismatch`] if its
    /// names or shapes differ from the model's; [`NnError::NonFiniteParameter`] if
    /// it holds NaN or infinity. On any error the parameters are unchanged.
    pub fn load(&mut self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let file_error = |message: String| NnError::File {
            path: path.to_path_buf(),
            message,
        };
        let mismatch = |message: String| NnError::Mismatch {
            path: path.to_path_buf(),
            message,
        };
        let file = std::fs::File::open(path).map_err(|e| file_error(e.to_string()))?;
        let mut npz = NpzReader::new(file).map_err(|e| file_error(e.to_string()))?;
        let mut in_file: Vec<String> = npz
            .names()
            .map_err(|e| file_error(e.to_string()))?
            .into_iter()
            .map(|n| n.strip_suffix(".npy").map(str::to_string).unwrap_or(n))
            .collect();
        in_file.sort();
        let mut expected = self.names.clone();
        expected.sort();
        if in_file != expected {
            let missing: Vec<_> = expected.iter().filter(|n| !in_file.contains(n)).collect();
            let extra: Vec<_> = in_file.iter().filter(|n| !expected.contains(n)).collect();
            return Err(mismatch(format!(
                "missing {missing:?}, not in the model {extra:?}"
            )));
        }
        let mut loaded = Vec::with_capacity(self.values.len());
        for (name, v) in self.names.iter().zip(&self.values) {
            let a: ArrayD<T> = npz
                .by_name(name)
                .map_err(|e| file_error(format!("reading {name:?}: {e}")))?;
            if a.shape() != v.shape() {
                return Err(mismatch(format!(
                    "{name:?} has shape {:?} in the file, {:?} in the model",
                    a.shape(),
                    v.shape()
                )));
            }
            loaded.push(a);
        }
        let candidate = Params {
            names: self.names.clone(),
            values: loaded,
        };
        candidate.check_finite()?;
        *self = candidate;
        Ok(())
    }
}

/// The parameters of a [`Params`] as variables of one tape.
#[derive(Debug, Clone)]
pub struct Bound<'t, T: Real> {
    vars: Vec<Var<'t, T>>,
}

impl<'t, T: Real> Bound<'t, T> {
    /// Parameters given as variables already recorded, in the order of the
    /// [`Params`] they stand for (for gradient checks, which create their own
    /// variables).
    pub fn from_vars(vars: Vec<Var<'t, T>>) -> Self {
        Bound { vars }
    }

    /// The variable of a parameter.
    pub fn get(&self, id: ParamId) -> Var<'t, T> {
        self.vars[id.0]
    }

    /// All variables, in the order of [`Params`]; pass them to
    /// [`Tape::backward`] as the variables to differentiate.
    pub fn vars(&self) -> &[Var<'t, T>] {
        &self.vars
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn init_is_seeded_and_within_its_bound() {
        let mut r1 = rand::rngs::StdRng::seed_from_u64(3);
        let mut r2 = rand::rngs::StdRng::seed_from_u64(3);
        let a: ArrayD<f64> = Init::He.sample(&[16, 8], 8, 16, &mut r1);
        let b: ArrayD<f64> = Init::He.sample(&[16, 8], 8, 16, &mut r2);
        assert_eq!(a, b);
        let bound = (6.0_f64 / 8.0).sqrt();
        assert!(a.iter().all(|x| x.abs() <= bound));
        // The sample variance is near a²/3 = 2/fan_in = 0.25.
        let var = a.iter().map(|x| x * x).sum::<f64>() / a.len() as f64;
        assert!((var - 0.25).abs() < 0.06, "{var}");
    }

    #[test]
    fn duplicate_names_are_refused() {
        let mut p = Params::<f64>::new();
        p.add("w", ArrayD::zeros(IxDyn(&[2]))).unwrap();
        assert!(matches!(
            p.add("w", ArrayD::zeros(IxDyn(&[2]))),
            Err(NnError::DuplicateName { .. })
        ));
    }
}
