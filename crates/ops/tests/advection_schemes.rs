//! The unit tests of each advection scheme, moved from
//! crates/ops/src/advection: the formulas by hand, gradients on every
//! boundary, CFL and input errors (the fused ops against their primitive
//! chains and the adjoint tests through the facade are in `advection.rs`).

mod upwind {
    use diffphys_ops::advection::{
        upwind1, upwind1_vjp, upwind2, AdvectionParams, Upwind1, Upwind2, Wants,
    };
    use diffphys_ops::{Boundary, Grid1, Grid2, OpsError};
    use diffphys_tape::{check_gradient, test_array, ArrayD, GradCheckOptions};
    use ndarray::{Array1, Array2, Array3, Ix1, Ix2};

    const KINDS: [Boundary; 3] = [
        Boundary::Periodic,
        Boundary::ZeroDirichlet,
        Boundary::Closed,
    ];

    /// A velocity of one sign with magnitudes in [0.2, 1] · `scale`, kept away
    /// from zero (where `min(u, 0)` and `max(u, 0)` have kinks).
    fn velocity(shape: &[usize], seed: u64, sign: f64, scale: f64) -> ArrayD<f64> {
        test_array::<f64>(shape, seed).mapv(|v| sign * scale * (0.6 + 0.4 * v))
    }

    /// Mixed signs, still away from zero.
    fn mixed_velocity(shape: &[usize], seed: u64, scale: f64) -> ArrayD<f64> {
        test_array::<f64>(shape, seed)
            .mapv(|v| scale * if v < 0.0 { v - 0.2 } else { v + 0.2 } / 1.2)
    }

    #[test]
    fn seed_formula_by_hand() {
        // dx = 0.5, dt = 0.1: a = 0.2.
        let grid = Grid1::new(4, 0.5, 0.0, Boundary::Periodic).unwrap();
        let d = ndarray::arr1(&[1.0f64, 2.0, 4.0, 8.0]);
        let u = ndarray::arr1(&[1.0, -2.0, 0.0, 3.0]);
        let out = upwind1(&grid, &AdvectionParams::new(0.1), d.view(), u.view()).unwrap();
        // i=0: u>0, m = 0.2: 1 − 0.2·(1 − 8) = 2.4
        // i=1: u<0, p = −0.4: 2 + 0.4·(4 − 2) = 2.8
        // i=2: u=0: 4
        // i=3: m = 0.6: 8 − 0.6·(8 − 4) = 5.6
        let want = [2.4, 2.8, 4.0, 5.6];
        for (o, w) in out.iter().zip(want) {
            assert!((o - w).abs() < 1e-14, "{out}");
        }
        // Zero Dirichlet: ghost 0 on the left of cell 0: 1 − 0.2·(1 − 0) = 0.8.
        let g0 = Grid1::new(4, 0.5, 0.0, Boundary::ZeroDirichlet).unwrap();
        let out0 = upwind1(&g0, &AdvectionParams::new(0.1), d.view(), u.view()).unwrap();
        assert!((out0[0] - 0.8).abs() < 1e-14);
    }

    #[test]
    fn gradients_1d_match_finite_differences() {
        let n = 9;
        for b in KINDS {
            let grid = Grid1::new(n, 0.1, 0.0, b).unwrap();
            let params = AdvectionParams::new(0.05);
            for (k, u) in [
                velocity(&[n], 1, 1.0, 1.5),
                velocity(&[n], 2, -1.0, 1.5),
                mixed_velocity(&[n], 3, 1.8),
            ]
            .into_iter()
            .enumerate()
            {
                let d = test_array::<f64>(&[n], 10 + k as u64);
                let report = check_gradient(
                    |t, v| {
                        // two steps, so the field gradient also flows into the velocity one
                        let d1 = t.apply(Upwind1::new(grid, params), &[v[0], v[1]])?;
                        t.apply(Upwind1::new(grid, params), &[d1, v[1]])
                    },
                    &[d, u],
                    GradCheckOptions::for_type::<f64>(),
                )
                .unwrap();
                assert!(report.passed, "{b:?} velocity {k}: {report:?}");
            }
        }
    }

    #[test]
    fn gradients_2d_match_finite_differences() {
        let (nx, ny) = (5, 4);
        for bx in KINDS {
            for by in [Boundary::Periodic, Boundary::ZeroDirichlet] {
                let grid = Grid2::new(nx, ny, 0.1, 0.2, bx)
                    .unwrap()
                    .with_boundaries(bx, by);
                let params = AdvectionParams::new(0.03);
                for (k, u) in [
                    velocity(&[2, nx, ny], 1, 1.0, 1.5),
                    velocity(&[2, nx, ny], 2, -1.0, 1.5),
                    mixed_velocity(&[2, nx, ny], 3, 2.0),
                ]
                .into_iter()
                .enumerate()
                {
                    let d = test_array::<f64>(&[nx, ny], 20 + k as u64);
                    let report = check_gradient(
                        |t, v| {
                            let d1 = t.apply(Upwind2::new(grid, params), &[v[0], v[1]])?;
                            t.apply(Upwind2::new(grid, params), &[d1, v[1]])
                        },
                        &[d, u],
                        GradCheckOptions::for_type::<f64>(),
                    )
                    .unwrap();
                    assert!(report.passed, "{bx:?}/{by:?} velocity {k}: {report:?}");
                }
            }
        }
    }

    #[test]
    fn two_d_with_one_cell_across_y_is_the_1d_scheme() {
        let grid2 = Grid2::new(6, 1, 0.1, 0.1, Boundary::Periodic).unwrap();
        let grid1 = Grid1::new(6, 0.1, 0.0, Boundary::Periodic).unwrap();
        let d = test_array::<f64>(&[6], 1);
        let u = mixed_velocity(&[6], 2, 1.0)
            .into_dimensionality::<Ix1>()
            .unwrap();
        let mut u2 = Array3::zeros((2, 6, 1));
        u2.slice_mut(ndarray::s![0, .., 0]).assign(&u);
        u2.slice_mut(ndarray::s![1, .., 0]).fill(0.7); // no effect: periodic, one cell
        let p = AdvectionParams::new(0.05);
        let d1 = upwind1(
            &grid1,
            &p,
            d.view().into_dimensionality().unwrap(),
            u.view(),
        )
        .unwrap();
        let d2 = upwind2(
            &grid2,
            &p,
            d.view().into_shape_with_order((6, 1)).unwrap(),
            u2.view(),
        )
        .unwrap();
        for (a, b) in d1.iter().zip(d2.iter()) {
            assert!((a - b).abs() < 1e-15);
        }
    }

    #[test]
    fn vjp_computes_only_what_is_asked() {
        let grid = Grid1::new(5, 0.1, 0.0, Boundary::Periodic).unwrap();
        let p = AdvectionParams::new(0.01);
        let (d, u) = (Array1::zeros(5), Array1::ones(5));
        let g = Array1::ones(5);
        let only_u = Wants {
            field: false,
            velocity: true,
        };
        let r = upwind1_vjp(&grid, &p, d.view(), u.view(), g.view(), only_u).unwrap();
        assert!(r.field.is_none() && r.velocity.is_some());
        // On the tape: a constant field needs no gradient, so the op returns none.
        let tape = diffphys_tape::Tape::<f64>::new();
        let dv = tape.constant(d.into_dyn());
        let uv = tape.var(u.into_dyn());
        let out = tape
            .apply(Upwind1::new(grid, p), &[dv, uv])
            .unwrap()
            .sum()
            .unwrap();
        let grads = tape.backward(out, &[uv]).unwrap();
        assert!(grads.get(uv).is_some());
    }

    #[test]
    fn cfl_violation_is_an_error_unless_allowed() {
        let grid = Grid1::new(4, 0.1, 0.0, Boundary::Periodic).unwrap();
        let d = Array1::<f64>::zeros(4);
        let u = ndarray::arr1(&[0.0, -3.0, 1.0, 0.5]);
        // Courant number 3·0.05/0.1 = 1.5
        let err = upwind1(&grid, &AdvectionParams::new(0.05), d.view(), u.view()).unwrap_err();
        match err {
            OpsError::Cfl { courant, limit, .. } => {
                assert!((courant - 1.5).abs() < 1e-12);
                assert_eq!(limit, 1.0);
            }
            other => panic!("expected a CFL error, got {other:?}"),
        }
        let allowed = AdvectionParams::new(0.05).allowing_cfl_violation();
        assert!(upwind1(&grid, &allowed, d.view(), u.view()).is_ok());
        // Exactly at the limit is fine.
        assert!(upwind1(&grid, &AdvectionParams::new(1.0 / 30.0), d.view(), u.view()).is_ok());

        // 2D: the sum over axes counts: 0.8·0.1/0.1 + 0.8·0.1/0.2 = 1.2.
        let g2 = Grid2::new(3, 3, 0.1, 0.2, Boundary::Periodic).unwrap();
        let u2 = Array3::from_elem((2, 3, 3), 0.8);
        let err = upwind2(
            &g2,
            &AdvectionParams::new(0.1),
            Array2::zeros((3, 3)).view(),
            u2.view(),
        );
        assert!(matches!(err, Err(OpsError::Cfl { .. })), "{err:?}");
        // And through the tape it is a tape error carrying the CFL error.
        let tape = diffphys_tape::Tape::<f64>::new();
        let dv = tape.var(d.into_dyn());
        let uv = tape.var(u.into_dyn());
        let err = tape
            .apply(Upwind1::new(grid, AdvectionParams::new(0.05)), &[dv, uv])
            .unwrap_err();
        assert!(err.to_string().contains("CFL"), "{err}");
    }

    #[test]
    fn bad_inputs_are_errors() {
        let grid = Grid1::new(4, 0.1, 0.0, Boundary::Periodic).unwrap();
        let d = Array1::<f64>::zeros(4);
        let short = Array1::<f64>::zeros(3);
        let p = AdvectionParams::new(0.01);
        assert!(matches!(
            upwind1(&grid, &p, d.view(), short.view()),
            Err(OpsError::ShapeMismatch { .. })
        ));
        let nan = ndarray::arr1(&[0.0, f64::NAN, 0.0, 0.0]);
        assert!(matches!(
            upwind1(&grid, &p, d.view(), nan.view()),
            Err(OpsError::NonFinite { .. })
        ));
        assert!(upwind1(&grid, &AdvectionParams::new(-1.0), d.view(), d.view()).is_err());
    }

    #[test]
    fn mass_is_conserved_with_a_constant_periodic_velocity() {
        let grid = Grid2::new(8, 6, 0.1, 0.1, Boundary::Periodic).unwrap();
        let d = test_array::<f64>(&[8, 6], 4)
            .into_dimensionality::<Ix2>()
            .unwrap();
        let mut u = Array3::zeros((2, 8, 6));
        u.slice_mut(ndarray::s![0, .., ..]).fill(0.3);
        u.slice_mut(ndarray::s![1, .., ..]).fill(-0.5);
        let d1 = upwind2(&grid, &AdvectionParams::new(0.1), d.view(), u.view()).unwrap();
        assert!((d1.sum() - d.sum()).abs() < 1e-12);
    }
}

mod semi_lagrangian {
    use diffphys_ops::advection::{
        semi_lagrangian1, semi_lagrangian2, semi_lagrangian2_vjp, SemiLagrangian1, SemiLagrangian2,
        Wants,
    };
    use diffphys_ops::{Boundary, Grid1, Grid2};
    use diffphys_tape::{
        check_adjoint, check_gradient, test_array, ArrayD, ArrayViewD, GradCheckOptions,
    };
    use ndarray::{Array1, Array2, Ix1, Ix3};

    const KINDS: [Boundary; 3] = [
        Boundary::Periodic,
        Boundary::ZeroDirichlet,
        Boundary::Closed,
    ];

    /// Velocities whose displacement `u·dt/h` is `k + φ` cells with an integer
    /// `k ∈ [−2, 2]` and a fraction `φ ∈ [0.2, 0.8]`: away from the kinks at
    /// whole cells, so that finite differences see one linear piece.
    fn velocity(shape: &[usize], seed: u64, cells_per_unit: f64) -> ArrayD<f64> {
        let r = test_array::<f64>(shape, seed);
        let s = test_array::<f64>(shape, seed + 99);
        ndarray::Zip::from(&r)
            .and(&s)
            .map_collect(|&r, &s| ((2.5 * r).round() + 0.5 + 0.3 * s) / cells_per_unit)
    }

    #[test]
    fn whole_cell_displacement_shifts_and_linear_fields_interpolate_exactly() {
        let grid = Grid1::new(6, 0.5, 0.0, Boundary::Periodic).unwrap();
        let d = ndarray::arr1(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        // u·dt/dx = 1·1/0.5 = 2 cells to the right
        let u = Array1::from_elem(6, 1.0);
        let out = semi_lagrangian1(&grid, 1.0, d.view(), u.view()).unwrap();
        assert_eq!(out, ndarray::arr1(&[5.0, 6.0, 1.0, 2.0, 3.0, 4.0]));
        // 0.3 cells left on a closed grid: d' = d(x + 0.15) = i + 1.3 inside, and
        // the last cell clamps to the edge value 6.
        let closed = Grid1::new(6, 0.5, 0.0, Boundary::Closed).unwrap();
        let u = Array1::from_elem(6, -0.15);
        let out = semi_lagrangian1(&closed, 1.0, d.view(), u.view()).unwrap();
        for i in 0..5 {
            assert!((out[i] - (i as f64 + 1.3)).abs() < 1e-14, "{out}");
        }
        assert_eq!(out[5], 6.0);
        // Zero Dirichlet reads 0 beyond the edge: cell 0 samples between the ghost
        // (0) and cell 0 with weight 0.3 on the ghost: 0.7·1.
        let zero = Grid1::new(6, 0.5, 0.0, Boundary::ZeroDirichlet).unwrap();
        let u = Array1::from_elem(6, 0.15);
        let out = semi_lagrangian1(&zero, 1.0, d.view(), u.view()).unwrap();
        assert!((out[0] - 0.7).abs() < 1e-14);
    }

    #[test]
    fn field_adjoint_passes_the_dot_product_test() {
        for b in KINDS {
            let grid = Grid2::new(6, 5, 0.2, 0.1, b).unwrap();
            let u = velocity(&[2, 6, 5], 3, 1.0)
                .into_dimensionality::<Ix3>()
                .unwrap();
            let dt = 0.2; // displacements k + φ cells along x, twice that along y
            let apply = |x: ArrayViewD<'_, f64>| {
                semi_lagrangian2(&grid, dt, x.into_dimensionality().unwrap(), u.view())
                    .unwrap()
                    .into_dyn()
            };
            let transpose = |y: ArrayViewD<'_, f64>| {
                let z = Array2::zeros((6, 5));
                let wants = Wants {
                    field: true,
                    velocity: false,
                };
                let y = y.into_dimensionality().unwrap();
                semi_lagrangian2_vjp(&grid, dt, z.view(), u.view(), y, wants)
                    .unwrap()
                    .field
                    .unwrap()
                    .into_dyn()
            };
            let x = test_array::<f64>(&[6, 5], 1);
            let y = test_array::<f64>(&[6, 5], 2);
            let r = check_adjoint(apply, transpose, x.view(), y.view()).unwrap();
            assert!(r.passes(1e-14), "{b:?}: {r:?}");
        }
    }

    #[test]
    fn gradients_1d_match_finite_differences() {
        let n = 8;
        for b in KINDS {
            let grid = Grid1::new(n, 0.25, 0.0, b).unwrap();
            let dt = 0.5; // displacement u·dt/dx = 2u cells
            for seed in [1, 2, 3] {
                let u = velocity(&[n], seed, 2.0);
                let d = test_array::<f64>(&[n], 10 + seed);
                let report = check_gradient(
                    |t, v| {
                        let d1 = t.apply(SemiLagrangian1::new(grid, dt), &[v[0], v[1]])?;
                        t.apply(SemiLagrangian1::new(grid, dt), &[d1, v[1]])
                    },
                    &[d, u],
                    GradCheckOptions::for_type::<f64>(),
                )
                .unwrap();
                assert!(report.passed, "{b:?} seed {seed}: {report:?}");
            }
        }
    }

    #[test]
    fn gradients_2d_match_finite_differences() {
        let (nx, ny) = (5, 4);
        for bx in KINDS {
            for by in KINDS {
                let grid = Grid2::new(nx, ny, 0.5, 0.5, bx)
                    .unwrap()
                    .with_boundaries(bx, by);
                let dt = 0.5; // u·dt/h = u cells
                let u = velocity(&[2, nx, ny], 5, 1.0);
                let d = test_array::<f64>(&[nx, ny], 6);
                let report = check_gradient(
                    |t, v| {
                        let d1 = t.apply(SemiLagrangian2::new(grid, dt), &[v[0], v[1]])?;
                        t.apply(SemiLagrangian2::new(grid, dt), &[d1, v[1]])
                    },
                    &[d, u],
                    GradCheckOptions::for_type::<f64>(),
                )
                .unwrap();
                assert!(report.passed, "{bx:?}/{by:?}: {report:?}");
            }
        }
    }

    #[test]
    fn self_advection_gradient_sums_both_roles() {
        // One Burgers-like step u' = SL(u, u): the field is its own velocity.
        let n = 8;
        let grid = Grid1::new(n, 0.25, 0.0, Boundary::Periodic).unwrap();
        let u = velocity(&[n], 7, 2.0);
        let report = check_gradient(
            |t, v| t.apply(SemiLagrangian1::new(grid, 0.5), &[v[0], v[0]]),
            &[u],
            GradCheckOptions::for_type::<f64>(),
        )
        .unwrap();
        assert!(report.passed, "{report:?}");
    }

    #[test]
    fn no_cfl_limit_but_non_finite_velocity_is_an_error() {
        let grid = Grid1::new(5, 0.1, 0.0, Boundary::Periodic).unwrap();
        let d = test_array::<f64>(&[5], 1)
            .into_dimensionality::<Ix1>()
            .unwrap();
        // 37 cells: 7 periods and 2 cells
        let u = Array1::from_elem(5, 3.7);
        let out = semi_lagrangian1(&grid, 1.0, d.view(), u.view()).unwrap();
        for i in 0..5 {
            assert!((out[i] - d[(i + 3) % 5]).abs() < 1e-12);
        }
        let bad = ndarray::arr1(&[0.0, f64::INFINITY, 0.0, 0.0, 0.0]);
        assert!(semi_lagrangian1(&grid, 1.0, d.view(), bad.view()).is_err());
    }
}
