//! The corrector: its size and the network.

use diffphys::flow::Scene;
use diffphys::learn::{Corrector, StateVars};
use diffphys::nn::{Arithmetic, Bound, Conv2, ConvConfig, Init, Layer, Padding, Params};
use diffphys::tape::{ArrayD, TapeError, Var};
use rand::Rng;

use super::{free_faces, re_code, Result, WakeError};

/// The corrector's size: a ResNet of `width` channels and `blocks` residual
/// blocks (two 3 × 3 convolutions each).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NetSize {
    /// Channels of the hidden layers.
    pub width: usize,
    /// Residual blocks.
    pub blocks: usize,
}

impl NetSize {
    /// Parses a label `wXbY` (width X, Y blocks).
    ///
    /// # Errors
    /// [`WakeError::Argument`] for anything else or a zero width.
    pub fn parse(label: &str) -> Result<Self> {
        let bad = || WakeError::Argument {
            option: "--capacity-sizes".into(),
            message: format!("not a size wXbY (width X, Y blocks): {label:?}"),
        };
        let (w, b) = label
            .strip_prefix('w')
            .and_then(|r| r.split_once('b'))
            .ok_or_else(bad)?;
        let width: usize = w.parse().map_err(|_| bad())?;
        let blocks: usize = b.parse().map_err(|_| bad())?;
        if width == 0 {
            return Err(bad());
        }
        Ok(NetSize { width, blocks })
    }

    /// A short label, `w16b2`.
    pub fn label(&self) -> String {
        format!("w{}b{}", self.width, self.blocks)
    }
}

impl std::fmt::Display for NetSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.label())
    }
}

/// The corrector: a ResNet on (`u_x`, `u_y`, Re code) over the packed lattice,
/// ReLU, its last layer starting at zero (the hybrid starts as the coarse
/// solver); its output is masked to the [`free_faces`].
pub struct Net {
    stem: Conv2,
    blocks: Vec<(Conv2, Conv2)>,
    head: Conv2,
    free: ArrayD<f64>,
    c_out: usize,
}

impl Net {
    /// A corrector of `size` for `scene` whose convolutions compute in
    /// `arithmetic`, with parameters drawn by `rng`.
    ///
    /// # Errors
    /// [`WakeError::Nn`] for a bad size.
    pub fn new(
        scene: &Scene,
        size: NetSize,
        arithmetic: Arithmetic,
        rng: &mut impl Rng,
    ) -> Result<(Self, Params<f64>)> {
        Self::with_outputs(scene, size, 2, arithmetic, rng)
    }

    /// As [`Net::new`] with `c_out` output channels (2 fit the state; another
    /// count is how a test provokes the shape error).
    ///
    /// # Errors
    /// As [`Net::new`].
    pub fn with_outputs(
        scene: &Scene,
        size: NetSize,
        c_out: usize,
        arithmetic: Arithmetic,
        rng: &mut impl Rng,
    ) -> Result<(Self, Params<f64>)> {
        let mut params = Params::new();
        let conv = |c_in, c_out, init| ConvConfig {
            c_in,
            c_out,
            kernel: 3,
            padding: Padding::Zero,
            init,
        };
        let w = size.width;
        let layer = |params: &mut Params<f64>, name: &str, config, rng: &mut _| {
            Conv2::new(params, name, config, rng).map(|c| c.with_arithmetic(arithmetic))
        };
        let stem = layer(&mut params, "stem", conv(3, w, Init::He), rng)?;
        let blocks = (0..size.blocks)
            .map(|b| {
                Ok((
                    layer(
                        &mut params,
                        &format!("block{b}.a"),
                        conv(w, w, Init::He),
                        rng,
                    )?,
                    layer(
                        &mut params,
                        &format!("block{b}.b"),
                        conv(w, w, Init::He),
                        rng,
                    )?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        let head = layer(&mut params, "head", conv(w, c_out, Init::Zeros), rng)?;
        Ok((
            Net {
                stem,
                blocks,
                head,
                free: free_faces(scene),
                c_out,
            },
            params,
        ))
    }
}

/// `a` repeated along a new leading axis `n` times.
fn repeat(a: &ArrayD<f64>, n: usize) -> ArrayD<f64> {
    let views: Vec<_> = (0..n).map(|_| a.view()).collect();
    ndarray::stack(ndarray::Axis(0), &views).expect("same shapes")
}

impl Corrector for Net {
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        state: &StateVars<'t>,
    ) -> diffphys::tape::Result<Vec<Var<'t, f64>>> {
        let state = state.only()?;
        let tape = state.tape();
        let shape = state.shape();
        let (n, a, b) = (shape[0], shape[2], shape[3]);
        if shape[1..] != self.free.shape()[..] {
            return Err(TapeError::shape(
                "wake corrector input",
                self.free.shape(),
                &shape[1..],
            ));
        }
        let free = tape.constant(repeat(&self.free, n));
        // The Re channel is data: read from each sample's viscosity corner.
        let values = state.to_array();
        let mut code = ArrayD::zeros(vec![n, 1, a, b]);
        for k in 0..n {
            let c = re_code(values[[k, 1, a - 1, b - 1]]);
            code.index_axis_mut(ndarray::Axis(0), k).fill(c);
        }
        let x = Var::concat(&[state.mul(free)?, tape.constant(code)], 1)?;
        let mut h = self.stem.forward(p, x)?.relu()?;
        for (c1, c2) in &self.blocks {
            let r = c1.forward(p, h)?.relu()?;
            h = h.add(c2.forward(p, r)?)?.relu()?;
        }
        let out = self.head.forward(p, h)?;
        if self.c_out != 2 {
            return Ok(vec![out]);
        }
        Ok(vec![out.mul(free)?])
    }
}

/// The corrector sizes of the capacity sweep (about 1.5k, 10k and 22k
/// parameters); the middle one is the main variants' size.
pub const SIZES: [NetSize; 3] = [
    NetSize {
        width: 8,
        blocks: 1,
    },
    NetSize {
        width: 16,
        blocks: 2,
    },
    NetSize {
        width: 24,
        blocks: 2,
    },
];

/// The main variants' corrector size.
pub const MAIN_SIZE: NetSize = SIZES[1];
