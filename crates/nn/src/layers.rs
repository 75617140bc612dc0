//! Layers: configuration plus the [`ParamId`]s of their parameters. A layer's
//! `forward` records its op on the tape of the [`Bound`] parameters it is given.

use diffphys_tape::{Real, Result, Var};
use rand::Rng;

use crate::conv::{Arithmetic, ConvOp, Padding};
use crate::dense::DenseOp;
use crate::params::{Bound, Init, ParamId, Params, Scalar};
use crate::resample::{Direction, Resample};
use crate::NnError;

/// Anything that maps one variable to another with the parameters of a model.
pub trait Layer<T: Real> {
    /// Records the layer applied to `x` on the tape `params` are bound to.
    ///
    /// # Errors
    /// [`diffphys_tape::TapeError::ShapeMismatch`] or
    /// [`diffphys_tape::TapeError::InvalidArgument`] naming the layer and the shapes if
    /// `x` does not fit it; whatever the tape returns.
    fn forward<'t>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>>;
}

/// A pointwise nonlinearity.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// `max(x, 0)`.
    Relu,
    /// `tanh x`.
    Tanh,
    /// The identity.
    Identity,
}

impl Activation {
    /// Records the activation of `x`.
    ///
    /// # Errors
    /// Whatever the tape returns.
    pub fn apply<'t, T: Real>(self, x: Var<'t, T>) -> Result<Var<'t, T>> {
        match self {
            Activation::Relu => x.relu(),
            Activation::Tanh => x.tanh(),
            Activation::Identity => Ok(x),
        }
    }

    /// The initialisation that keeps activations' variance: He for ReLU, Glorot
    /// otherwise.
    pub fn init(self) -> Init {
        match self {
            Activation::Relu => Init::He,
            _ => Init::Glorot,
        }
    }
}

/// A dense layer `y = x W + b` on `[batch, inputs]` (see [`crate::dense`]).
#[derive(Debug, Clone)]
pub struct Dense {
    name: String,
    weight: ParamId,
    bias: ParamId,
}

impl Dense {
    /// Adds `W` (`[inputs, outputs]`, drawn by `init`) and `b` (zeros) to
    /// `params` as `"{name}.weight"` and `"{name}.bias"`.
    ///
    /// # Errors
    /// [`NnError::DuplicateName`] if the names are taken; [`NnError::Config`] for
    /// zero sizes.
    pub fn new<T: Scalar>(
        params: &mut Params<T>,
        name: &str,
        inputs: usize,
        outputs: usize,
        init: Init,
        rng: &mut impl Rng,
    ) -> crate::Result<Self> {
        if inputs == 0 || outputs == 0 {
            return Err(NnError::Config {
                layer: name.to_string(),
                message: format!("{inputs} inputs and {outputs} outputs: both must be positive"),
            });
        }
        let weight = params.add_init(
            format!("{name}.weight"),
            &[inputs, outputs],
            init,
            (inputs, outputs),
            rng,
        )?;
        let bias = params.add_init(format!("{name}.bias"), &[outputs], Init::Zeros, (0, 0), rng)?;
        Ok(Dense {
            name: name.to_string(),
            weight,
            bias,
        })
    }
}

impl<T: Real> Layer<T> for Dense {
    fn forward<'t>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        let op = DenseOp {
            name: format!("dense {:?}", self.name),
        };
        x.tape()
            .apply(op, &[x, params.get(self.weight), params.get(self.bias)])
    }
}

/// A convolution layer of either dimension (see [`crate::conv`]); [`Conv1`] and
/// [`Conv2`] build it.
#[derive(Debug, Clone)]
struct Conv {
    name: String,
    padding: Padding,
    arithmetic: Arithmetic,
    threads: usize,
    weight: ParamId,
    bias: ParamId,
}

/// What a convolution layer is built from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvConfig {
    /// Input channels.
    pub c_in: usize,
    /// Output channels.
    pub c_out: usize,
    /// Kernel size along each spatial axis (odd).
    pub kernel: usize,
    /// Padding rule at the edges.
    pub padding: Padding,
    /// How the weights are drawn (biases start at zero).
    pub init: Init,
}

impl Conv {
    fn new<T: Scalar>(
        params: &mut Params<T>,
        kind: &str,
        name: &str,
        dims: usize,
        config: ConvConfig,
        rng: &mut impl Rng,
    ) -> crate::Result<Self> {
        let ConvConfig {
            c_in,
            c_out,
            kernel,
            padding,
            init,
        } = config;
        if c_in == 0 || c_out == 0 || kernel % 2 == 0 {
            return Err(NnError::Config {
                layer: format!("{kind} {name:?}"),
                message: format!(
                    "{c_in} → {c_out} channels with kernel {kernel}: channels must be \
                     positive and the kernel size odd"
                ),
            });
        }
        let taps = kernel.pow(dims as u32);
        let mut shape = vec![c_out, c_in];
        shape.extend(std::iter::repeat_n(kernel, dims));
        let weight = params.add_init(
            format!("{name}.weight"),
            &shape,
            init,
            (c_in * taps, c_out * taps),
            rng,
        )?;
        let bias = params.add_init(format!("{name}.bias"), &[c_out], Init::Zeros, (0, 0), rng)?;
        Ok(Conv {
            name: format!("{kind} {name:?}"),
            padding,
            arithmetic: Arithmetic::Native,
            threads: 1,
            weight,
            bias,
        })
    }

    fn with_threads(mut self, threads: usize) -> crate::Result<Self> {
        if threads == 0 {
            return Err(NnError::Config {
                layer: self.name,
                message: "0 threads: the forward pass needs at least one".into(),
            });
        }
        self.threads = threads;
        Ok(self)
    }

    fn forward<'t, T: Real>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        let op = ConvOp {
            name: self.name.clone(),
            padding: self.padding,
            arithmetic: self.arithmetic,
            threads: self.threads,
        };
        x.tape()
            .apply(op, &[x, params.get(self.weight), params.get(self.bias)])
    }
}

/// A 1D convolution on `[batch, c_in, n]` → `[batch, c_out, n]` ("same" size).
#[derive(Debug, Clone)]
pub struct Conv1(Conv);

impl Conv1 {
    /// Adds the kernel `[c_out, c_in, k]` and the bias `[c_out]` to `params` as
    /// `"{name}.weight"` and `"{name}.bias"`.
    ///
    /// # Errors
    /// [`NnError::DuplicateName`] if the names are taken; [`NnError::Config`] for
    /// zero channels or an even kernel size.
    pub fn new<T: Scalar>(
        params: &mut Params<T>,
        name: &str,
        config: ConvConfig,
        rng: &mut impl Rng,
    ) -> crate::Result<Self> {
        Conv::new(params, "conv1d", name, 1, config, rng).map(Conv1)
    }

    /// The layer computing in `arithmetic` (new layers compute in
    /// [`Arithmetic::Native`]).
    #[must_use]
    pub fn with_arithmetic(mut self, arithmetic: Arithmetic) -> Self {
        self.0.arithmetic = arithmetic;
        self
    }

    /// The layer with its forward pass split over `threads` threads (new
    /// layers run on one); its values are the same bit for bit, and its
    /// backward pass runs on one thread whatever `threads` is (see
    /// [`crate::conv::conv_forward`]).
    ///
    /// # Errors
    /// [`NnError::Config`] for zero threads.
    pub fn with_threads(self, threads: usize) -> crate::Result<Self> {
        self.0.with_threads(threads).map(Conv1)
    }
}

impl<T: Real> Layer<T> for Conv1 {
    fn forward<'t>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        self.0.forward(params, x)
    }
}

/// A 2D convolution on `[batch, c_in, h, w]` → `[batch, c_out, h, w]` ("same" size).
#[derive(Debug, Clone)]
pub struct Conv2(Conv);

impl Conv2 {
    /// Adds the kernel `[c_out, c_in, k, k]` and the bias `[c_out]` to `params` as
    /// `"{name}.weight"` and `"{name}.bias"`.
    ///
    /// # Errors
    /// As [`Conv1::new`].
    pub fn new<T: Scalar>(
        params: &mut Params<T>,
        name: &str,
        config: ConvConfig,
        rng: &mut impl Rng,
    ) -> crate::Result<Self> {
        Conv::new(params, "conv2d", name, 2, config, rng).map(Conv2)
    }

    /// The layer computing in `arithmetic` (new layers compute in
    /// [`Arithmetic::Native`]).
    #[must_use]
    pub fn with_arithmetic(mut self, arithmetic: Arithmetic) -> Self {
        self.0.arithmetic = arithmetic;
        self
    }

    /// The layer with its forward pass split over `threads` threads (new
    /// layers run on one); its values are the same bit for bit, and its
    /// backward pass runs on one thread whatever `threads` is (see
    /// [`crate::conv::conv_forward`]).
    ///
    /// # Errors
    /// [`NnError::Config`] for zero threads.
    pub fn with_threads(self, threads: usize) -> crate::Result<Self> {
        self.0.with_threads(threads).map(Conv2)
    }
}

impl<T: Real> Layer<T> for Conv2 {
    fn forward<'t>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        self.0.forward(params, x)
    }
}

/// 2× average pooling over the spatial axes, 1D or 2D (see [`crate::resample`]);
/// `2x` is the factor, not a dimension.
#[derive(Debug, Clone, Copy, Default)]
pub struct AvgPool2x;

impl<T: Real> Layer<T> for AvgPool2x {
    fn forward<'t>(&self, _params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        x.tape().apply(
            Resample {
                name: "avg_pool2".into(),
                direction: Direction::Pool,
            },
            &[x],
        )
    }
}

/// 2× nearest-neighbour upsampling over the spatial axes, 1D or 2D (see
/// [`crate::resample`]); `2x` is the factor, not a dimension.
#[derive(Debug, Clone, Copy, Default)]
pub struct Upsample2x;

impl<T: Real> Layer<T> for Upsample2x {
    fn forward<'t>(&self, _params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        x.tape().apply(
            Resample {
                name: "upsample2".into(),
                direction: Direction::Upsample,
            },
            &[x],
        )
    }
}
