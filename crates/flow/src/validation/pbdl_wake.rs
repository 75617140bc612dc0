//! The PBDL book's wake flow as PhiFlow runs it: the peer comparison's scene
//! (`benches/flow_peers`).

use crate::{Advection, Boundary, Obstacle, Scene, SceneBuilder, Sides, Splitting};

/// The PBDL book's wake flow as PhiFlow runs it (`benches/flow_peers`), in
/// our terms: a 100 × 200 domain of `res × 2 res` cells, uniform inflow 1 at
/// the bottom, outflow at the top, no-slip walls left and right, a cylinder
/// of radius 10 at (50, 50), explicit viscosity 1.25e-3 (the book's Re = 500
/// at its resolution factor 32), semi-Lagrangian advection, plain splitting,
/// dt = 1. Semi-Lagrangian advection is stable at any Courant number and
/// PhiFlow takes dt = 1 at every resolution (Courant ≈ 2 at 128 × 256, 12 at
/// 512 × 1024 where the flow passes the cylinder), so the Courant guard grows
/// with the grid. The builder is returned so that a caller can change the
/// scheme, the pressure solver or add scalars before [`SceneBuilder::build`].
pub fn pbdl_wake(res: usize) -> SceneBuilder {
    Scene::builder(res, 2 * res, [100.0, 200.0])
        .sides(Sides {
            left: Boundary::no_slip(),
            right: Boundary::no_slip(),
            bottom: Boundary::inflow(),
            top: Boundary::outflow(),
        })
        .obstacle(Obstacle::cylinder([50.0, 50.0], 10.0))
        .uniform_inflow(1.0)
        // PhiFlow's diffusivity dt · 32² / (Re / (10 / 128²)) at Re = 500, dt = 1
        .viscosity(32.0 * 32.0 * 10.0 / (128.0 * 128.0) / 500.0)
        .dt(1.0)
        .advection(Advection::SemiLagrangian)
        .splitting(Splitting::Plain)
        .max_courant(8.0f64.max(res as f64 / 16.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_wake_builds_at_the_peer_resolutions_with_the_book_viscosity() {
        for res in [16, 32] {
            let scene = pbdl_wake(res).build().unwrap();
            assert_eq!((scene.grid().nx, scene.grid().ny), (res, 2 * res));
            let nu: f64 = scene.params().viscosity;
            assert!((nu - 1.25e-3).abs() < 1e-15);
        }
    }
}
