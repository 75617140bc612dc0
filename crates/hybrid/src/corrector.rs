//! A residual convolutional corrector on the staggered grid's face lattice.

use std::str::FromStr;

use diffphys_flow::Scene;
use diffphys_learn::{Corrector, StateVars};
use diffphys_nn::{Arithmetic, Bound, Conv2, ConvConfig, Init, Layer, Padding, Params};
use diffphys_tape::{ArrayD, TapeError, Var};
use rand::Rng;

use crate::{free_faces, HybridError, Result};

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
    /// A short label, `w16b2`.
    pub fn label(&self) -> String {
        format!("w{}b{}", self.width, self.blocks)
    }

    /// A measure of the cost of one evaluation: the weights of its 3 × 3
    /// convolutions over the hidden channels, `width² (2 blocks + 2)`.
    pub fn cost(&self) -> usize {
        self.width * self.width * (2 * self.blocks + 2)
    }
}

impl FromStr for NetSize {
    type Err = HybridError;

    /// Parses a label `wXbY` (width X > 0, Y blocks).
    fn from_str(label: &str) -> Result<Self> {
        let bad = || HybridError::Size {
            label: label.to_string(),
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
}

impl std::fmt::Display for NetSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.label())
    }
}

/// How a sample's viscosity enters the network: the value of its input
/// channel (a scene codes the Reynolds number, e.g. `ln(Re / Re₀)`).
pub type ParamCode = fn(f64) -> f64;

/// A corrector for a [`crate::FlowSimulator`]'s state: a ResNet (3 × 3
/// convolutions, zero padding, ReLU) over the face lattice
/// `[nx + 1, ny + 1]` ([`free_faces`]) with three input channels, `u_x` and
/// `u_y` zero-padded to the lattice and masked to the free faces, and the
/// code of each sample's viscosity ([`ParamCode`]); one correction per
/// velocity component out, masked to its free faces. The head starts at
/// zero: the hybrid starts as the solver.
///
/// ```text
/// x = [M ⊙ pad(u_x), M ⊙ pad(u_y), code(ν)]
/// h₀ = relu(stem x),  h_{b+1} = relu(h_b + B_b(relu(A_b h_b))),  c = M ⊙ head h
/// ```
///
/// Its gradient is the tape's, through every op above, to the parameters and
/// the velocity; the code channel is data (each sample's `ν` read as a
/// number), so no gradient reaches `ν` through the network.
pub struct LatticeNet {
    stem: Conv2,
    blocks: Vec<(Conv2, Conv2)>,
    head: Conv2,
    free: ArrayD<f64>,
    code: ParamCode,
    c_out: usize,
}

impl std::fmt::Debug for LatticeNet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LatticeNet")
            .field("blocks", &self.blocks.len())
            .field("lattice", &self.free.shape())
            .field("c_out", &self.c_out)
            .finish()
    }
}

impl LatticeNet {
    /// A corrector of `size` for `scene` whose convolutions compute in
    /// `arithmetic`, with parameters drawn by `rng`.
    ///
    /// # Errors
    /// [`HybridError::Nn`] for a bad size.
    pub fn new(
        scene: &Scene,
        size: NetSize,
        code: ParamCode,
        arithmetic: Arithmetic,
        rng: &mut impl Rng,
    ) -> Result<(Self, Params<f64>)> {
        Self::with_outputs(scene, size, code, 2, arithmetic, rng)
    }

    /// As [`LatticeNet::new`] with `c_out` output channels (2 fit the state;
    /// another count is how a test provokes the learning library's shape
    /// error).
    ///
    /// # Errors
    /// As [`LatticeNet::new`].
    pub fn with_outputs(
        scene: &Scene,
        size: NetSize,
        code: ParamCode,
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
        let mut layer = |name: &str, config, rng: &mut _| {
            Conv2::new(&mut params, name, config, rng).map(|c| c.with_arithmetic(arithmetic))
        };
        let stem = layer("stem", conv(3, w, Init::He), rng)?;
        let blocks = (0..size.blocks)
            .map(|b| {
                Ok((
                    layer(&format!("block{b}.a"), conv(w, w, Init::He), rng)?,
                    layer(&format!("block{b}.b"), conv(w, w, Init::He), rng)?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        let head = layer("head", conv(w, c_out, Init::Zeros), rng)?;
        Ok((
            LatticeNet {
                stem,
                blocks,
                head,
                free: free_faces(scene),
                code,
                c_out,
            },
            params,
        ))
    }

    /// The corrector with every convolution's forward pass split over
    /// `threads` threads ([`Conv2::with_threads`]; new correctors run on
    /// one): the same corrections bit for bit, faster where the cores are
    /// free. Its backward pass stays on one thread.
    ///
    /// # Errors
    /// [`HybridError::Nn`] for zero threads.
    pub fn with_threads(self, threads: usize) -> Result<Self> {
        let LatticeNet {
            stem,
            blocks,
            head,
            free,
            code,
            c_out,
        } = self;
        let blocks = (blocks.into_iter())
            .map(|(a, b)| Ok((a.with_threads(threads)?, b.with_threads(threads)?)))
            .collect::<Result<Vec<_>>>()?;
        Ok(LatticeNet {
            stem: stem.with_threads(threads)?,
            blocks,
            head: head.with_threads(threads)?,
            free,
            code,
            c_out,
        })
    }
}

impl Corrector for LatticeNet {
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        state: &StateVars<'t>,
    ) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        let (Some(&ux), Some(&uy), Some(&nu)) = (
            state.fields.first(),
            state.fields.get(1),
            state.params.first(),
        ) else {
            return Err(TapeError::invalid(
                "lattice corrector",
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
        let batch: Vec<usize> = std::iter::once(n)
            .chain(self.free.shape().iter().copied())
            .collect();
        let free = (self.free.broadcast(batch).map(|v| v.to_owned()))
            .ok_or_else(|| TapeError::invalid("lattice corrector", "the free-face mask"))?;
        let free = tape.constant(free);
        // The viscosity channel is data: read from each sample's parameter.
        let values = nu.to_array();
        let mut code = ArrayD::zeros(vec![n, 1, a, b]);
        for (k, &v) in values.iter().enumerate() {
            code.index_axis_mut(ndarray::Axis(0), k)
                .fill((self.code)(v));
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
