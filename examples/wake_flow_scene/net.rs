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

/// The corrector: a ResNet on (`u_x`, `u_y`, Re code) over the lattice
/// `[nx + 1, ny + 1]` ([`free_faces`]),
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
    /// The velocity on the lattice (`u_x` and `u_y` zero-padded to
    /// `[nx + 1, ny + 1]` as two channels, masked to the free faces) and the
    /// Re code of each sample's viscosity in, one correction per velocity
    /// component out (masked to its free faces).
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        state: &StateVars<'t>,
    ) -> diffphys::tape::Result<Vec<Var<'t, f64>>> {
        let (Some(&ux), Some(&uy), Some(&nu)) = (
            state.fields.first(),
            state.fields.get(1),
            state.params.first(),
        ) else {
            return Err(TapeError::invalid(
                "wake corrector",
                "a state of u_x, u_y and a viscosity per sample",
            ));
        };
        let tape = ux.tape();
        let (a, b) = (self.free.shape()[1], self.free.shape()[2]);
        let n = ux.shape()[0];
        for (name, v, shape) in [("u_x", ux, [n, a, b - 1]), ("u_y", uy, [n, a - 1, b])] {
            if v.shape() != shape {
                return Err(TapeError::shape(name, &shape, &v.shape()));
            }
        }
        let lattice = Var::concat(
            &[
                ux.reshape(&[n, 1, a, b - 1])?.pad(3, 0, 1)?,
                uy.reshape(&[n, 1, a - 1, b])?.pad(2, 0, 1)?,
            ],
            1,
        )?;
        let free = tape.constant(repeat(&self.free, n));
        // The Re channel is data: read from each sample's viscosity.
        let values = nu.to_array();
        let mut code = ArrayD::zeros(vec![n, 1, a, b]);
        for (k, &v) in values.iter().enumerate() {
            code.index_axis_mut(ndarray::Axis(0), k).fill(re_code(v));
        }
        let x = Var::concat(&[lattice.mul(free)?, tape.constant(code)], 1)?;
        let mut h = self.stem.forward(p, x)?.relu()?;
        for (c1, c2) in &self.blocks {
            let r = c1.forward(p, h)?.relu()?;
            h = h.add(c2.forward(p, r)?)?.relu()?;
        }
        let mut out = self.head.forward(p, h)?;
        if self.c_out == 2 {
            out = out.mul(free)?;
        }
        // Channel 0 back to u_x's faces, channel 1 to u_y's; any further
        // channel (a wrong head) comes back whole, for the library to refuse.
        (0..self.c_out)
            .map(|c| {
                let ch = out.slice(1, c, c + 1)?;
                match c {
                    0 => ch.slice(3, 0, b - 1)?.reshape(&[n, a, b - 1]),
                    1 => ch.slice(2, 0, a - 1)?.reshape(&[n, a - 1, b]),
                    _ => ch.reshape(&[n, a, b]),
                }
            })
            .collect()
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
