//! Restriction of a state to a coarser grid of the same domain and sides:
//! the velocity by face averages, the pressure by cell averages.
//!
//! **Velocity.** [`restrict_velocity`] averages the fine faces that tile each
//! coarse face: `U_x[i, j] = (1/r) Σ_k u_x[r i, r j + k]` and the same along
//! y. The flux through every coarse face is the fine flux through it, so the
//! coarse divergence is the average of the fine divergence over each block of
//! `r × r` cells: a divergence-free fine field stays divergence-free.
//!
//! **Pressure.** [`restrict_pressure`] averages the `r × r` fine cells of each
//! coarse cell: `P[i, j] = (1/r²) Σ_{a, b} p[r i + a, r j + b]`.

use diffphys_tape::Real;
use ndarray::{s, Array2, ArrayView2};

use crate::{FlowError, FlowGrid, Result};

/// The velocity `(u_x, u_y)` of the grid `r` times finer than `coarse` (same
/// domain and sides) restricted to `coarse` by face averages (see the
/// [module docs](crate::restrict)).
///
/// # Errors
/// [`FlowError::InvalidParameter`] for `r = 0`; [`FlowError::Shape`] if the
/// fine velocity is not of the finer grid's shapes.
pub fn restrict_velocity<T: Real>(
    coarse: &FlowGrid,
    r: usize,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    const WHAT: &str = "velocity restriction";
    if r == 0 {
        return Err(FlowError::parameter(WHAT, "factor", "must be at least 1"));
    }
    let ([x0, x1], [y0, y1]) = (coarse.shape_x(), coarse.shape_y());
    let (px, py) = (coarse.periodic_x(), coarse.periodic_y());
    let fine_x = [r * coarse.nx + usize::from(!px), r * coarse.ny];
    let fine_y = [r * coarse.nx, r * coarse.ny + usize::from(!py)];
    if ux.shape() != fine_x {
        return Err(FlowError::shape(
            WHAT,
            "fine x-velocity",
            &fine_x,
            ux.shape(),
        ));
    }
    if uy.shape() != fine_y {
        return Err(FlowError::shape(
            WHAT,
            "fine y-velocity",
            &fine_y,
            uy.shape(),
        ));
    }
    let w = T::from_f64(1.0 / r as f64);
    let cx = Array2::from_shape_fn((x0, x1), |(i, j)| {
        ux.slice(s![r * i, r * j..r * (j + 1)]).sum() * w
    });
    let cy = Array2::from_shape_fn((y0, y1), |(i, j)| {
        uy.slice(s![r * i..r * (i + 1), r * j]).sum() * w
    });
    Ok((cx, cy))
}

/// The pressure of the grid `r` times finer than `coarse` restricted to
/// `coarse` by cell averages (see the [module docs](crate::restrict)).
///
/// # Errors
/// [`FlowError::InvalidParameter`] for `r = 0`; [`FlowError::Shape`] if the
/// fine pressure is not of the finer grid's cell shape.
pub fn restrict_pressure<T: Real>(
    coarse: &FlowGrid,
    r: usize,
    p: ArrayView2<'_, T>,
) -> Result<Array2<T>> {
    const WHAT: &str = "pressure restriction";
    if r == 0 {
        return Err(FlowError::parameter(WHAT, "factor", "must be at least 1"));
    }
    let fine = [r * coarse.nx, r * coarse.ny];
    if p.shape() != fine {
        return Err(FlowError::shape(WHAT, "fine pressure", &fine, p.shape()));
    }
    let w = T::from_f64(1.0 / (r * r) as f64);
    Ok(Array2::from_shape_fn((coarse.nx, coarse.ny), |(i, j)| {
        p.slice(s![r * i..r * (i + 1), r * j..r * (j + 1)]).sum() * w
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostics::divergence;
    use crate::step::Splitting;
    use crate::{Boundary, FlowState, Scene, Sides};

    fn channel(nx: usize, ny: usize) -> Scene {
        Scene::builder(nx, ny, [2.0, 1.0])
            .sides(Sides {
                left: Boundary::inflow(),
                right: Boundary::outflow(),
                bottom: Boundary::free_slip(),
                top: Boundary::free_slip(),
            })
            .uniform_inflow(1.0)
            .viscosity(0.01)
            .dt(0.02)
            .splitting(Splitting::Plain)
            .build()
            .unwrap()
    }

    fn state(scene: &Scene) -> FlowState<f64> {
        let g = scene.grid();
        let wobble =
            |a: usize, b: usize, k: f64| 1.0 + 0.3 * (a as f64 * 0.7 + b as f64 * 1.3 + k).sin();
        let ux = Array2::from_shape_fn(g.shape_x(), |(a, b)| wobble(a, b, 0.0));
        let uy = Array2::from_shape_fn(g.shape_y(), |(a, b)| 0.2 * wobble(a, b, 2.0) - 0.2);
        let mut s = FlowState::from_velocity(scene, ux, uy);
        s.pressure = Array2::from_shape_fn(g.cell_shape(), |(a, b)| wobble(a, b, 5.0));
        s
    }

    #[test]
    fn restriction_averages_the_divergence_over_blocks() {
        // Without an obstacle: the divergence of every cell is the raw D u.
        let coarse = channel(6, 4);
        let fine = channel(18, 12);
        let s = state(&fine);
        let (ux, uy) = restrict_velocity(coarse.grid(), 3, s.ux.view(), s.uy.view()).unwrap();
        let dc = divergence(&coarse, ux.view(), uy.view()).unwrap();
        let df = divergence(&fine, s.ux.view(), s.uy.view()).unwrap();
        for ((i, j), &d) in dc.indexed_iter() {
            let block = df.slice(s![3 * i..3 * i + 3, 3 * j..3 * j + 3]).sum() / 9.0;
            // Each divergence is D u with u scaled by 1/h: compare relative to it.
            assert!((d - block).abs() < 1e-10 * (1.0 + block.abs()), "{i},{j}");
        }
        assert!(matches!(
            restrict_velocity(coarse.grid(), 2, s.ux.view(), s.uy.view()),
            Err(FlowError::Shape { .. })
        ));
    }

    #[test]
    fn the_pressure_restricts_to_block_means_and_keeps_its_mean() {
        let coarse = channel(6, 4);
        let fine = channel(18, 12);
        let s = state(&fine);
        let p = restrict_pressure(coarse.grid(), 3, s.pressure.view()).unwrap();
        assert_eq!(p.shape(), &[6, 4]);
        let block = s.pressure.slice(s![3..6, 6..9]).sum() / 9.0;
        assert!((p[[1, 2]] - block).abs() < 1e-14);
        let means = (p.mean().unwrap(), s.pressure.mean().unwrap());
        assert!((means.0 - means.1).abs() < 1e-13, "{means:?}");
        assert!(matches!(
            restrict_pressure(coarse.grid(), 2, s.pressure.view()),
            Err(FlowError::Shape { .. })
        ));
        assert!(matches!(
            restrict_pressure(coarse.grid(), 0, s.pressure.view()),
            Err(FlowError::InvalidParameter { .. })
        ));
    }
}
