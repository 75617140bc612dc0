//! A small U-Net in 1D or 2D: convolutions at every scale, 2× average pooling
//! down, nearest upsampling up, skip connections by channel concatenation, and a
//! 1×1 head that starts at zero (so an untrained network outputs zeros, the
//! baseline every scene compares against).
//!
//! With `L = widths.len() − 1` levels, the field's spatial sizes must be
//! divisible by `2^L`.
//!
//! # References
//! O. Ronneberger, P. Fischer, T. Brox, *U-Net: convolutional networks for
//! biomedical image segmentation*, MICCAI 2015.

use diffphys_tape::{Real, Result, Var};
use rand::Rng;

use crate::conv::Padding;
use crate::layers::{Activation, AvgPool2x, Conv1, Conv2, ConvConfig, Layer, Upsample2x};
use crate::params::{Bound, Init, Params, Scalar};
use crate::NnError;

/// The shape of a [`UNet`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UNetConfig {
    /// 1 for `[batch, c, n]` fields, 2 for `[batch, c, h, w]`.
    pub dims: usize,
    /// Input channels.
    pub c_in: usize,
    /// Output channels.
    pub c_out: usize,
    /// Channels at each scale, finest first; the last is the bottom of the U.
    pub widths: Vec<usize>,
    /// Convolution kernel size (odd).
    pub kernel: usize,
    /// Padding of every convolution.
    pub padding: Padding,
    /// The nonlinearity after every convolution but the head.
    pub activation: Activation,
}

/// One of the two convolution kinds.
#[derive(Debug, Clone)]
enum AnyConv {
    D1(Conv1),
    D2(Conv2),
}

impl AnyConv {
    fn new<T: Scalar>(
        params: &mut Params<T>,
        dims: usize,
        name: &str,
        config: ConvConfig,
        rng: &mut impl Rng,
    ) -> crate::Result<Self> {
        Ok(if dims == 1 {
            AnyConv::D1(Conv1::new(params, name, config, rng)?)
        } else {
            AnyConv::D2(Conv2::new(params, name, config, rng)?)
        })
    }

    fn forward<'t, T: Real>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        match self {
            AnyConv::D1(c) => c.forward(params, x),
            AnyConv::D2(c) => c.forward(params, x),
        }
    }
}

/// Two convolutions, each followed by the activation.
#[derive(Debug, Clone)]
struct Block {
    first: AnyConv,
    second: AnyConv,
}

/// A U-Net (see the module docs).
#[derive(Debug, Clone)]
pub struct UNet {
    config: UNetConfig,
    down: Vec<Block>,
    bottom: Block,
    up: Vec<Block>,
    head: AnyConv,
}

impl UNet {
    /// Adds the network's parameters to `params`, named `"{name}.down0.a.weight"`
    /// and so on, drawn from `rng` (He for ReLU, Glorot otherwise; the head and
    /// every bias start at zero).
    ///
    /// # Errors
    /// [`NnError::Config`] for `dims` other than 1 or 2, no widths, zero channels
    /// or an even kernel; [`NnError::DuplicateName`] if the names are taken.
    pub fn new<T: Scalar>(
        params: &mut Params<T>,
        name: &str,
        config: UNetConfig,
        rng: &mut impl Rng,
    ) -> crate::Result<Self> {
        if !(1..=2).contains(&config.dims) || config.widths.is_empty() {
            return Err(NnError::Config {
                layer: format!("unet {name:?}"),
                message: format!(
                    "dims {} with widths {:?}: dims must be 1 or 2 and there must be \
                     at least one width",
                    config.dims, config.widths
                ),
            });
        }
        let conv = |c_in, c_out, kernel, init| ConvConfig {
            c_in,
            c_out,
            kernel,
            padding: config.padding,
            init,
        };
        let act_init = config.activation.init();
        let k = config.kernel;
        let d = config.dims;
        let block = |params: &mut Params<T>, label: String, c_in, c_out, rng: &mut _| {
            Ok::<_, NnError>(Block {
                first: AnyConv::new(
                    params,
                    d,
                    &format!("{label}.a"),
                    conv(c_in, c_out, k, act_init),
                    rng,
                )?,
                second: AnyConv::new(
                    params,
                    d,
                    &format!("{label}.b"),
                    conv(c_out, c_out, k, act_init),
                    rng,
                )?,
            })
        };
        let levels = config.widths.len() - 1;
        let mut down = Vec::with_capacity(levels);
        let mut c = config.c_in;
        for (i, &w) in config.widths[..levels].iter().enumerate() {
            down.push(block(params, format!("{name}.down{i}"), c, w, rng)?);
            c = w;
        }
        let bottom = block(
            params,
            format!("{name}.bottom"),
            c,
            config.widths[levels],
            rng,
        )?;
        let mut up = Vec::with_capacity(levels);
        for i in (0..levels).rev() {
            let (w, coarse) = (config.widths[i], config.widths[i + 1]);
            up.push(block(params, format!("{name}.up{i}"), w + coarse, w, rng)?);
        }
        let head = AnyConv::new(
            params,
            d,
            &format!("{name}.head"),
            conv(config.widths[0], config.c_out, 1, Init::Zeros),
            rng,
        )?;
        Ok(UNet {
            config,
            down,
            bottom,
            up,
            head,
        })
    }

    /// Its configuration.
    pub fn config(&self) -> &UNetConfig {
        &self.config
    }

    /// Pooling levels.
    pub fn levels(&self) -> usize {
        self.down.len()
    }

    /// Cells along one axis of the input that can influence one output cell
    /// (through the deepest path): `r = (k − 1)/2` per convolution, scaled by
    /// each level's coarsening. When it reaches the grid's size, every output cell
    /// sees the whole field.
    pub fn receptive_field(&self) -> usize {
        let r = (self.config.kernel - 1) / 2;
        let levels = self.levels();
        // Two convolutions per block; a block at level l moves 2^l fine cells per
        // tap; pooling and upsampling widen by 2^l − 1 on each side at most.
        let mut reach = 0;
        for l in 0..levels {
            reach += 2 * 2 * r * (1 << l) + (1 << l);
        }
        reach += 2 * r * (1 << levels);
        2 * reach + 1
    }
}

impl<T: Real> Layer<T> for UNet {
    fn forward<'t>(&self, params: &Bound<'t, T>, x: Var<'t, T>) -> Result<Var<'t, T>> {
        let act = self.config.activation;
        let run = |b: &Block, h: Var<'t, T>| -> Result<Var<'t, T>> {
            let h = act.apply(b.first.forward(params, h)?)?;
            act.apply(b.second.forward(params, h)?)
        };
        let mut skips = Vec::with_capacity(self.down.len());
        let mut h = x;
        for b in &self.down {
            h = run(b, h)?;
            skips.push(h);
            h = AvgPool2x.forward(params, h)?;
        }
        h = run(&self.bottom, h)?;
        for b in &self.up {
            let skip = skips.pop().expect("one skip per level");
            h = Upsample2x.forward(params, h)?;
            h = Var::concat(&[skip, h], 1)?;
            h = run(b, h)?;
        }
        self.head.forward(params, h)
    }
}
