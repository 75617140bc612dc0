//! Upwind and semi-Lagrangian advection through the facade: each fused op against
//! the same scheme written in tape primitives (its reference), finite-difference
//! gradient checks for both inputs on both boundary kinds with positive, negative
//! and mixed velocities (2D upwind also with closed walls in y), the dot-product
//! test of the field adjoints (1D and 2D, both schemes), and CFL errors.

mod common;

use common::*;
use diffphys_ops::advection::{
    semi_lagrangian1, semi_lagrangian1_vjp, semi_lagrangian2, semi_lagrangian2_vjp, upwind1,
    upwind1_vjp, upwind2, upwind2_vjp, AdvectionParams, SemiLagrangian1, SemiLagrangian2, Upwind1,
    Upwind2, Wants,
};
use diffphys_ops::{Boundary, Grid1, Grid2, OpsError};
use ndarray::{Array1, Array3, ArrayViewD, Ix1, Ix2, Ix3};

/// A velocity with entries of magnitude in `[0.2, 1]·scale`, of one sign (`sign =
/// ±1`) or of both (`sign = 0`): away from 0, where `min(u, 0)` and `max(u, 0)`
/// have their kinks.
fn velocity<T: Real>(shape: &[usize], seed: u64, sign: f64, scale: f64) -> ArrayD<T> {
    random_field::<f64>(shape, seed).mapv(|r| {
        let magnitude = scale * (0.6 + 0.4 * r.abs().mul_add(2.0, -1.0));
        let s = if sign == 0.0 { r.signum() } else { sign };
        T::from_f64(s * magnitude)
    })
}

/// The 1D upwind step written in primitives, the reference of the fused op:
/// neighbours by `roll` (periodic) or by `pad` + `slice` (zero ghosts).
fn upwind_1d_primitives<'t, T: Real>(
    grid: &Grid1,
    dt: f64,
    d: Var<'t, T>,
    u: Var<'t, T>,
) -> diffphys_tape::Result<Var<'t, T>> {
    let n = grid.n;
    let zero = d.tape().scalar(T::zero());
    let c = u.mul_scalar(T::from_f64(1.0 / grid.dx))?;
    let (u_plus, u_minus) = (zero.minimum(c)?, zero.maximum(c)?);
    let (next, prev) = match grid.boundary {
        Boundary::Periodic => (d.roll(-1, 0)?, d.roll(1, 0)?),
        Boundary::ZeroDirichlet => {
            let padded = d.pad(0, 1, 1)?;
            (padded.slice(0, 2, n + 2)?, padded.slice(0, 0, n)?)
        }
        Boundary::Closed => unreachable!("not used here"),
    };
    let rate = u_plus.mul(next.sub(d)?)?.add(u_minus.mul(d.sub(prev)?)?)?;
    d.sub(rate.mul_scalar(T::from_f64(dt))?)
}

/// The 2D upwind step in primitives on a periodic grid.
fn upwind_2d_primitives<'t, T: Real>(
    grid: &Grid2,
    dt: f64,
    d: Var<'t, T>,
    u: Var<'t, T>,
) -> diffphys_tape::Result<Var<'t, T>> {
    let shape = [grid.nx, grid.ny];
    let zero = d.tape().scalar(T::zero());
    let mut out = d;
    for (axis, h) in [(0, grid.dx), (1, grid.dy)] {
        let c = u
            .slice(0, axis, axis + 1)?
            .reshape(&shape)?
            .mul_scalar(T::from_f64(1.0 / h))?;
        let (u_plus, u_minus) = (zero.minimum(c)?, zero.maximum(c)?);
        let next = d.roll(-1, axis)?.sub(d)?;
        let prev = d.sub(d.roll(1, axis)?)?;
        let rate = u_plus.mul(next)?.add(u_minus.mul(prev)?)?;
        out = out.sub(rate.mul_scalar(T::from_f64(dt))?)?;
    }
    Ok(out)
}

/// Three steps, value and gradients in both inputs, op against primitives.
fn upwind_op_matches_its_primitive_chain<T: Real>() {
    let n = 24;
    for b in [Boundary::Periodic, Boundary::ZeroDirichlet] {
        let grid = Grid1::new(n, 0.1, 0.0, b).unwrap();
        let p = AdvectionParams::new(0.04);
        for sign in [1.0, -1.0, 0.0] {
            let d0 = random_field::<T>(&[n], 1);
            let u0 = velocity::<T>(&[n], 2, sign, 2.0);
            let w = random_field::<T>(&[n], 3);
            let run = |fused: bool| {
                let tape = Tape::<T>::new();
                let (d, u) = (tape.var(d0.clone()), tape.var(u0.clone()));
                let mut x = d;
                for _ in 0..3 {
                    x = if fused {
                        x.tape().apply(Upwind1::new(grid, p), &[x, u]).unwrap()
                    } else {
                        upwind_1d_primitives(&grid, p.dt, x, u).unwrap()
                    };
                }
                let loss = x.dot(tape.constant(w.clone())).unwrap();
                let g = tape.backward(loss, &[d, u]).unwrap();
                (
                    x.to_array(),
                    g.get(d).unwrap().clone(),
                    g.get(u).unwrap().clone(),
                )
            };
            let (fused, chain) = (run(true), run(false));
            assert_close(&fused.0, &chain.0, "upwind value");
            assert_close(&fused.1, &chain.1, "upwind ∂/∂d");
            assert_close(&fused.2, &chain.2, "upwind ∂/∂u");
        }
    }
    let grid = Grid2::new(6, 5, 0.1, 0.2, Boundary::Periodic).unwrap();
    let p = AdvectionParams::new(0.03);
    let d0 = random_field::<T>(&[6, 5], 4);
    let u0 = velocity::<T>(&[2, 6, 5], 5, 0.0, 2.0);
    let w = random_field::<T>(&[6, 5], 6);
    let run = |fused: bool| {
        let tape = Tape::<T>::new();
        let (d, u) = (tape.var(d0.clone()), tape.var(u0.clone()));
        let x = if fused {
            tape.apply(Upwind2::new(grid, p), &[d, u]).unwrap()
        } else {
            upwind_2d_primitives(&grid, p.dt, d, u).unwrap()
        };
        let loss = x.dot(tape.constant(w.clone())).unwrap();
        let g = tape.backward(loss, &[d, u]).unwrap();
        (
            x.to_array(),
            g.get(d).unwrap().clone(),
            g.get(u).unwrap().clone(),
        )
    };
    let (fused, chain) = (run(true), run(false));
    assert_close(&fused.0, &chain.0, "upwind 2D value");
    assert_close(&fused.1, &chain.1, "upwind 2D ∂/∂d");
    assert_close(&fused.2, &chain.2, "upwind 2D ∂/∂u");
}

/// The upwind field adjoint by the dot-product test (the map `d ↦ d'` is linear
/// for a fixed velocity).
fn upwind_field_adjoint_passes_the_dot_product_test<T: Real>() {
    for b in [
        Boundary::Periodic,
        Boundary::ZeroDirichlet,
        Boundary::Closed,
    ] {
        let grid = Grid1::new(17, 0.1, 0.0, b).unwrap();
        let p = AdvectionParams::new(0.04);
        let u = velocity::<T>(&[17], 7, 0.0, 2.0)
            .into_dimensionality::<Ix1>()
            .unwrap();
        let apply = |x: ArrayViewD<'_, T>| {
            upwind1(&grid, &p, x.into_dimensionality().unwrap(), u.view())
                .unwrap()
                .into_dyn()
        };
        let transpose = |y: ArrayViewD<'_, T>| {
            let z = Array1::zeros(17);
            let wants = Wants {
                field: true,
                velocity: false,
            };
            upwind1_vjp(
                &grid,
                &p,
                z.view(),
                u.view(),
                y.into_dimensionality().unwrap(),
                wants,
            )
            .unwrap()
            .field
            .unwrap()
            .into_dyn()
        };
        let x = random_field::<T>(&[17], 8);
        let y = random_field::<T>(&[17], 9);
        let report = check_adjoint(apply, transpose, x.view(), y.view()).unwrap();
        assert_adjoint_ok::<T>(&report);
    }
}

/// The 2D upwind field adjoint by the dot-product test, on every boundary kind
/// and with closed walls in y only (periodic in x).
fn upwind_2d_field_adjoint_passes_the_dot_product_test<T: Real>() {
    let grids = [
        Grid2::new(7, 5, 0.1, 0.15, Boundary::Periodic).unwrap(),
        Grid2::new(7, 5, 0.1, 0.15, Boundary::ZeroDirichlet).unwrap(),
        Grid2::new(7, 5, 0.1, 0.15, Boundary::Closed).unwrap(),
        Grid2::new(7, 5, 0.1, 0.15, Boundary::Periodic)
            .unwrap()
            .with_boundaries(Boundary::Periodic, Boundary::Closed),
    ];
    for grid in grids {
        let p = AdvectionParams::new(0.03);
        let u = velocity::<T>(&[2, 7, 5], 40, 0.0, 1.5)
            .into_dimensionality::<Ix3>()
            .unwrap();
        let apply = |x: ArrayViewD<'_, T>| {
            upwind2(&grid, &p, x.into_dimensionality().unwrap(), u.view())
                .unwrap()
                .into_dyn()
        };
        let transpose = |y: ArrayViewD<'_, T>| {
            let z = ndarray::Array2::zeros((7, 5));
            let wants = Wants {
                field: true,
                velocity: false,
            };
            let y = y.into_dimensionality::<Ix2>().unwrap();
            upwind2_vjp(&grid, &p, z.view(), u.view(), y, wants)
                .unwrap()
                .field
                .unwrap()
                .into_dyn()
        };
        let x = random_field::<T>(&[7, 5], 41);
        let y = random_field::<T>(&[7, 5], 42);
        let report = check_adjoint(apply, transpose, x.view(), y.view()).unwrap();
        assert_adjoint_ok::<T>(&report);
    }
}

both_precisions!(
    upwind_op_matches_its_primitive_chain,
    upwind_field_adjoint_passes_the_dot_product_test,
    upwind_2d_field_adjoint_passes_the_dot_product_test
);

/// 2D upwind with closed walls in y (zero flux through them) and periodic or
/// closed in x: gradients in the field and the velocity against finite
/// differences, for velocities of each sign.
#[test]
fn upwind_2d_with_closed_walls_in_y_matches_finite_differences() {
    for bx in [Boundary::Periodic, Boundary::Closed] {
        for sign in [1.0, -1.0, 0.0] {
            let grid = Grid2::new(6, 5, 0.1, 0.15, bx)
                .unwrap()
                .with_boundaries(bx, Boundary::Closed);
            let p = AdvectionParams::new(0.04);
            let d = random_field::<f64>(&[6, 5], 43);
            let u = velocity::<f64>(&[2, 6, 5], 44, sign, 1.5);
            assert_gradient(
                |t, v| {
                    let d1 = t.apply(Upwind2::new(grid, p), &[v[0], v[1]])?;
                    t.apply(Upwind2::new(grid, p), &[d1, v[1]])
                },
                &[d, u],
            );
        }
    }
}

#[test]
fn upwind_gradients_match_finite_differences() {
    for b in [Boundary::Periodic, Boundary::ZeroDirichlet] {
        for sign in [1.0, -1.0, 0.0] {
            let grid = Grid1::new(13, 0.1, 0.0, b).unwrap();
            let p = AdvectionParams::new(0.04);
            let d = random_field::<f64>(&[13], 10);
            let u = velocity::<f64>(&[13], 11, sign, 2.0);
            assert_gradient(
                |t, v| {
                    let d1 = t.apply(Upwind1::new(grid, p), &[v[0], v[1]])?;
                    t.apply(Upwind1::new(grid, p), &[d1, v[1]])
                },
                &[d, u],
            );
            let grid2 = Grid2::new(6, 4, 0.1, 0.15, b).unwrap();
            let d = random_field::<f64>(&[6, 4], 12);
            let u = velocity::<f64>(&[2, 6, 4], 13, sign, 1.5);
            assert_gradient(
                |t, v| {
                    let d1 = t.apply(Upwind2::new(grid2, p), &[v[0], v[1]])?;
                    t.apply(Upwind2::new(grid2, p), &[d1, v[1]])
                },
                &[d, u],
            );
        }
    }
}

/// Velocities whose displacement is `k + φ` cells, `k ∈ [−2, 2]` whole and
/// `φ ∈ [0.2, 0.8]`, so finite differences stay on one linear piece.
fn sl_velocity(shape: &[usize], seed: u64, cells_per_unit: f64, sign: f64) -> ArrayD<f64> {
    let r = random_field::<f64>(shape, seed);
    let s = random_field::<f64>(shape, seed + 50);
    ndarray::Zip::from(&r).and(&s).map_collect(|&r, &s| {
        let whole = if sign == 0.0 {
            (2.5 * r).round()
        } else {
            sign * (1.5 * r.abs()).round()
        };
        (whole + 0.5 + 0.3 * s) / cells_per_unit
    })
}

#[test]
fn semi_lagrangian_gradients_match_finite_differences() {
    // Periodic and clamped (closed) sampling, and zero beyond zero-Dirichlet walls.
    for b in [
        Boundary::Periodic,
        Boundary::Closed,
        Boundary::ZeroDirichlet,
    ] {
        for sign in [1.0, -1.0, 0.0] {
            let grid = Grid1::new(12, 0.25, 0.0, b).unwrap();
            let dt = 0.5; // u·dt/dx = 2u cells
            let d = random_field::<f64>(&[12], 20);
            let u = sl_velocity(&[12], 21, 2.0, sign);
            assert_gradient(
                |t, v| {
                    let d1 = t.apply(SemiLagrangian1::new(grid, dt), &[v[0], v[1]])?;
                    t.apply(SemiLagrangian1::new(grid, dt), &[d1, v[1]])
                },
                &[d, u],
            );
            let grid2 = Grid2::new(6, 5, 0.25, 0.5, b).unwrap();
            let d = random_field::<f64>(&[6, 5], 22);
            // dt/dx = 2 but dt/dy = 1: doubling u_y makes both displacements
            // whole-plus-fraction cells.
            let mut u = sl_velocity(&[2, 6, 5], 23, 2.0, sign);
            u.index_axis_mut(ndarray::Axis(0), 1)
                .mapv_inplace(|v| 2.0 * v);
            assert_gradient(
                |t, v| {
                    let d1 = t.apply(SemiLagrangian2::new(grid2, dt), &[v[0], v[1]])?;
                    t.apply(SemiLagrangian2::new(grid2, dt), &[d1, v[1]])
                },
                &[d, u],
            );
        }
    }
}

fn semi_lagrangian_field_adjoint_passes_the_dot_product_test<T: Real>() {
    for b in [
        Boundary::Periodic,
        Boundary::Closed,
        Boundary::ZeroDirichlet,
    ] {
        let grid = Grid2::new(7, 4, 0.2, 0.3, b).unwrap();
        let u = velocity::<T>(&[2, 7, 4], 30, 0.0, 1.3)
            .into_dimensionality::<Ix3>()
            .unwrap();
        let dt = 0.35;
        let apply = |x: ArrayViewD<'_, T>| {
            semi_lagrangian2(&grid, dt, x.into_dimensionality().unwrap(), u.view())
                .unwrap()
                .into_dyn()
        };
        let transpose = |y: ArrayViewD<'_, T>| {
            let z = ndarray::Array2::zeros((7, 4));
            let wants = Wants {
                field: true,
                velocity: false,
            };
            let y = y.into_dimensionality::<Ix2>().unwrap();
            semi_lagrangian2_vjp(&grid, dt, z.view(), u.view(), y, wants)
                .unwrap()
                .field
                .unwrap()
                .into_dyn()
        };
        let x = random_field::<T>(&[7, 4], 31);
        let y = random_field::<T>(&[7, 4], 32);
        let report = check_adjoint(apply, transpose, x.view(), y.view()).unwrap();
        assert_adjoint_ok::<T>(&report);
    }
}

/// The 1D semi-Lagrangian field adjoint by the dot-product test, on every
/// boundary kind, with displacements of several cells either way.
fn semi_lagrangian_1d_field_adjoint_passes_the_dot_product_test<T: Real>() {
    for b in [
        Boundary::Periodic,
        Boundary::Closed,
        Boundary::ZeroDirichlet,
    ] {
        let grid = Grid1::new(15, 0.2, 0.0, b).unwrap();
        let u = velocity::<T>(&[15], 50, 0.0, 1.3)
            .into_dimensionality::<Ix1>()
            .unwrap();
        let dt = 0.5; // up to 3.25 cells
        let apply = |x: ArrayViewD<'_, T>| {
            semi_lagrangian1(&grid, dt, x.into_dimensionality().unwrap(), u.view())
                .unwrap()
                .into_dyn()
        };
        let transpose = |y: ArrayViewD<'_, T>| {
            let z = Array1::zeros(15);
            let wants = Wants {
                field: true,
                velocity: false,
            };
            let y = y.into_dimensionality::<Ix1>().unwrap();
            semi_lagrangian1_vjp(&grid, dt, z.view(), u.view(), y, wants)
                .unwrap()
                .field
                .unwrap()
                .into_dyn()
        };
        let x = random_field::<T>(&[15], 51);
        let y = random_field::<T>(&[15], 52);
        let report = check_adjoint(apply, transpose, x.view(), y.view()).unwrap();
        assert_adjoint_ok::<T>(&report);
    }
}

both_precisions!(
    semi_lagrangian_field_adjoint_passes_the_dot_product_test,
    semi_lagrangian_1d_field_adjoint_passes_the_dot_product_test
);

#[test]
fn upwind_at_courant_one_and_semi_lagrangian_at_whole_cells_shift_exactly() {
    let grid = Grid1::new(10, 0.1, 0.0, Boundary::Periodic).unwrap();
    let d = random_field::<f64>(&[10], 40)
        .into_dimensionality::<Ix1>()
        .unwrap();
    // u = −1, dt = 0.1: Courant number 1 to the left, d'_i = d_{i+1}.
    let u = Array1::from_elem(10, -1.0);
    let up = upwind1(&grid, &AdvectionParams::new(0.1), d.view(), u.view()).unwrap();
    // The same velocity over 0.3 is three cells for semi-Lagrangian: d'_i = d_{i+3}.
    let sl = semi_lagrangian1(&grid, 0.3, d.view(), u.view()).unwrap();
    for i in 0..10 {
        assert!((up[i] - d[(i + 1) % 10]).abs() < 1e-15);
        assert!((sl[i] - d[(i + 3) % 10]).abs() < 1e-12);
    }
}

#[test]
fn cfl_violations_are_typed_errors_unless_allowed() {
    let grid = Grid2::new(4, 4, 0.1, 0.1, Boundary::ZeroDirichlet).unwrap();
    let d = ndarray::Array2::<f64>::zeros((4, 4));
    let mut u = Array3::<f64>::zeros((2, 4, 4));
    u[[1, 2, 3]] = -2.5; // Courant number 2.5·0.05/0.1 = 1.25
    let p = AdvectionParams::new(0.05);
    match upwind2(&grid, &p, d.view(), u.view()) {
        Err(OpsError::Cfl { courant, limit, op }) => {
            assert!((courant - 1.25).abs() < 1e-12);
            assert_eq!(limit, 1.0);
            assert_eq!(op, "upwind_2d");
        }
        other => panic!("expected a CFL error, got {other:?}"),
    }
    assert!(upwind2(&grid, &p.allowing_cfl_violation(), d.view(), u.view()).is_ok());
    // Semi-Lagrangian has no CFL limit.
    assert!(semi_lagrangian2(&grid, 0.05, d.view(), u.view()).is_ok());
    // On the tape the error names the op.
    let tape = Tape::<f64>::new();
    let dv = tape.var(d.into_dyn());
    let uv = tape.var(u.into_dyn());
    let err = tape.apply(Upwind2::new(grid, p), &[dv, uv]).unwrap_err();
    assert!(err.to_string().contains("upwind_2d"), "{err}");
}
