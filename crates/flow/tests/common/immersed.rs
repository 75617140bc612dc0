//! The immersed circle's test scenes, shared by `immersed.rs` and
//! `immersed_schemes.rs`.

use diffphys_flow::{Circle, ForcingScheme, Interior, Scene, Sides};
use ndarray::Array2;

pub const CENTRE: [f64; 2] = [0.62, 0.47];
pub const RADIUS: f64 = 0.2;

/// A 24 × 12 channel 2 × 1 with the immersed circle of `shape`, its cells solid.
pub fn scene(shape: [f64; 3]) -> Scene {
    scene_with(shape, Interior::Solid)
}

/// [`scene`] with the circle's inside `interior`.
pub fn scene_with(shape: [f64; 3], interior: Interior) -> Scene {
    scene_scheme(shape, interior, ForcingScheme::Direct)
}

/// [`scene_with`] forced by `scheme`.
pub fn scene_scheme(shape: [f64; 3], interior: Interior, scheme: ForcingScheme) -> Scene {
    Scene::builder(24, 12, [2.0, 1.0])
        .sides(Sides::channel())
        .immersed(Circle::new([shape[0], shape[1]], shape[2]).unwrap())
        .immersed_interior(interior)
        .immersed_scheme(scheme)
        .parabolic_inflow(1.0)
        .viscosity(0.02)
        .dt(0.02)
        .build()
        .unwrap()
}

/// The circle's `[centre x, centre y, radius]`.
pub fn shape() -> [f64; 3] {
    [CENTRE[0], CENTRE[1], RADIUS]
}

/// `Σ a b` over the entries.
pub fn dot(a: &Array2<f64>, b: &Array2<f64>) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
