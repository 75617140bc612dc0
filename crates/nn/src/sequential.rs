//! Layers in a row: [`Sequential`] (any layers, applied in order) and [`Mlp`]
//! (dense layers with an activation between them), the small networks that
//! map a state vector to a correction or a parameter guess.
//!
//! ```
//! use diffphys_nn::{Activation, Layer, Mlp, Params};
//! use diffphys_tape::Tape;
//! use rand::SeedableRng;
//!
//! let mut params = Params::<f64>::new();
//! let mut rng = rand::rngs::StdRng::seed_from_u64(1);
//! // 3 inputs → 16 → 16 → 2 outputs, tanh between the dense layers.
//! let mlp = Mlp::new(&mut params, "mlp", &[3, 16, 16, 2], Activation::Tanh, &mut rng)?;
//! let tape = Tape::new();
//! let p = params.bind(&tape);
//! let x = tape.constant(ndarray::Array2::<f64>::ones((5, 3))); // a batch of 5
//! let y = mlp.forward(&p, x)?;
//! assert_eq!(y.shape(), vec![5, 2]);
//! let grads = tape.backward(y.sum()?, p.vars())?;
//! assert!(p.vars().iter().all(|&v| grads.get(v).is_some())); // W and b of three layers
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use diffphys_tape::{Real, Result, Var};
use rand::Rng;

use crate::layers::{Activation, Dense, Layer};
use crate::params::{Bound, Params, Scalar};
use crate::NnError;

/// Layers applied one after the other: `y = f_n(… f_2(f_1(x)))`. Its
/// gradient is the tape's, through each layer's own adjoint.
pub struct Sequential<T: Real> {
    layers: Vec<Box<dyn Layer<T>>>,
}

impl<T: Real> std::fmt::Debug for Sequential<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sequential")
            .field("layers", &self.layers.len())
            .finish()
    }
}

impl<T: Real> Default for Sequential<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Real> Sequential<T> {
    /// No layers (the identity).
    pub fn new() -> Self {
        Sequential { layers: Vec::new() }
    }

    /// With `layer` appended.
    pub fn with(mut self, layer: impl Layer<T> + 'static) -> Self {
        self.push(layer);
        self
    }

    /// Appends `layer`.
    pub fn push(&mut self, layer: impl Layer<T> + 'static) {
        self.layers.push(Box::new(layer));
    }

    /// The number of layers.
    pub fn len(&self) -> usize {
        self.layers.len()
    }

    /// Whether it has no layers.
    pub fn is_empty(&self) -> bool {
        self.layers.is_empty()
    }
}

impl<T: Real> Layer<T> for Sequential<T> {
    fn forward<'t>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        self.layers
            .iter()
            .try_fold(x, |h, layer| layer.forward(params, h))
    }
}

/// A multilayer perceptron on `[batch, sizes[0]]` → `[batch, sizes[last]]`:
/// dense layers `y = x W + b` with `activation` after every one but the last
/// (the output is linear).
///
/// Hidden layers are initialised for the activation (He for ReLU, Glorot
/// otherwise), the last one Glorot; biases start at zero; every draw comes from
/// the caller's seeded `rng`.
#[derive(Debug, Clone)]
pub struct Mlp {
    layers: Vec<Dense>,
    activation: Activation,
}

impl Mlp {
    /// Adds the layers `"{name}.0"`, `"{name}.1"`, … (each with its
    /// `.weight` and `.bias`) to `params`.
    ///
    /// # Errors
    /// [`NnError::Config`] for fewer than two sizes or a zero size;
    /// [`NnError::DuplicateName`] if the names are taken.
    pub fn new<T: Scalar>(
        params: &mut Params<T>,
        name: &str,
        sizes: &[usize],
        activation: Activation,
        rng: &mut impl Rng,
    ) -> crate::Result<Self> {
        if sizes.len() < 2 {
            return Err(NnError::Config {
                layer: format!("mlp {name:?}"),
                message: format!("sizes {sizes:?}: need at least the input and the output size"),
            });
        }
        let last = sizes.len() - 2;
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(k, io)| {
                let init = if k == last {
                    Activation::Identity.init()
                } else {
                    activation.init()
                };
                Dense::new(params, &format!("{name}.{k}"), io[0], io[1], init, rng)
            })
            .collect::<crate::Result<Vec<_>>>()?;
        Ok(Mlp { layers, activation })
    }

    /// The number of dense layers.
    pub fn depth(&self) -> usize {
        self.layers.len()
    }
}

impl<T: Real> Layer<T> for Mlp {
    fn forward<'t>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        let last = self.layers.len() - 1;
        let mut h = x;
        for (k, dense) in self.layers.iter().enumerate() {
            h = dense.forward(params, h)?;
            if k < last {
                h = self.activation.apply(h)?;
            }
        }
        Ok(h)
    }
}

/// An activation is a layer without parameters.
impl<T: Real> Layer<T> for Activation {
    fn forward<'t>(&self, _params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        self.apply(x)
    }
}
