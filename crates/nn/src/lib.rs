//! # diffphys-nn
//!
//! Neural networks for training through differentiable solvers, built on the
//! `diffphys-tape` tape alone. Layers are tape ops with hand-written adjoints
//! ([`Dense`], [`Conv1`], [`Conv2`], 2× pooling and upsampling, an [`Mlp`], a
//! [`UNet`], any of them in a [`Sequential`]), so a
//! network records a handful of nodes and joins the solver's ops on one tape.
//! A model owns its [`Params`]: seeded initialisation, a parameter count, and
//! `.npz` save and load that round-trips bit for bit.
//!
//! One training step records on a fresh tape, binds the parameters to it, and
//! applies an optimizer to the gradients:
//!
//! ```
//! use diffphys_nn::{Activation, Conv1, ConvConfig, Init, Layer, Padding, Params};
//! use diffphys_tape::{Adam, ArrayD, IxDyn, Tape};
//! use rand::SeedableRng;
//!
//! let mut rng = rand::rngs::StdRng::seed_from_u64(7);
//! let mut params = Params::<f64>::new();
//! let config = ConvConfig { c_in: 1, c_out: 1, kernel: 3, padding: Padding::Periodic, init: Init::Glorot };
//! let conv = Conv1::new(&mut params, "smooth", config, &mut rng)?;
//! // Learn the periodic 3-point average of a [batch 2, channel 1, 8 cells] field.
//! let x = diffphys_tape::test_array::<f64>(&[2, 1, 8], 1);
//! let target = (&x + &x.view().to_owned().mapv(|v| v)) / 2.0; // any fixed target
//! let mut adam = Adam::new(0.05);
//! let mut losses = Vec::new();
//! for _ in 0..100 {
//!     let tape = Tape::new();
//!     let p = params.bind(&tape);
//!     let y = Activation::Identity.apply(conv.forward(&p, tape.constant(x.clone()))?)?;
//!     let loss = y.sub(tape.constant(target.clone()))?.powi(2)?.mean()?;
//!     losses.push(loss.item()?);
//!     let grads = tape.backward(loss, p.vars())?;
//!     params.step(&mut adam, &grads, &p)?;
//! }
//! assert!(losses[99] < 1e-3 * losses[0]);
//! # let _ = ArrayD::<f64>::zeros(IxDyn(&[1]));
//! # Ok::<(), diffphys_nn::NnError>(())
//! ```
#![warn(missing_docs)]

pub mod conv;
pub mod dense;
mod error;
mod layers;
mod params;
pub mod reference;
pub mod resample;
mod sequential;
mod train;
mod unet;

pub use conv::{Arithmetic, ConvOp, Padding};
pub use error::{NnError, Result};
pub use layers::{Activation, AvgPool2x, Conv1, Conv2, ConvConfig, Dense, Layer, Upsample2x};
pub use params::{Bound, Init, ParamId, Params, Scalar};
pub use sequential::{Mlp, Sequential};
pub use train::{check_loss, stack};
pub use unet::{UNet, UNetConfig};
