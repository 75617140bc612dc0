//! The corrector: the hybrid library's lattice ResNet, fed the Reynolds
//! number's code, at the sizes of the capacity sweep.

use diffphys::flow::Scene;
use diffphys::hybrid::{LatticeNet, NetSize};
use diffphys::nn::{Arithmetic, Params};
use rand::Rng;

use super::{re_code, Result};

/// The corrector ([`LatticeNet`]: the velocity on the face lattice and the
/// Re code of each sample's viscosity in, one correction per velocity
/// component out).
pub type Net = LatticeNet;

/// A corrector of `size` for `scene` whose convolutions compute in
/// `arithmetic`, with parameters drawn by `rng`; its Re channel is
/// [`re_code`].
///
/// # Errors
/// [`super::WakeError::Hybrid`] for a bad size.
pub fn net(
    scene: &Scene,
    size: NetSize,
    arithmetic: Arithmetic,
    rng: &mut impl Rng,
) -> Result<(Net, Params<f64>)> {
    Ok(LatticeNet::new(scene, size, re_code, arithmetic, rng)?)
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
