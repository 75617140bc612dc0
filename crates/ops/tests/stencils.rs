//! The stencil operators through the facade: the dot-product test in f32 and f64
//! for every operator and boundary, second-order convergence on manufactured
//! solutions, and gradients through the tape adapter.

mod common;

use std::sync::Arc;

use common::*;
use diffphys_ops::stencil::{
    DiffusionParams, Divergence1, Divergence2, ExplicitDiffusion1, ExplicitDiffusion2, Gradient1,
    Gradient2, Laplacian1, Laplacian2,
};
use diffphys_ops::tape_ops::LinearOp;
use diffphys_ops::{Boundary, Grid1, Grid2, LinearOperator};
use ndarray::{Array1, Array2, IxDyn};

const KINDS: [Boundary; 3] = [
    Boundary::Periodic,
    Boundary::ZeroDirichlet,
    Boundary::Closed,
];

/// Every stencil operator on a 1D grid and on a non-square 2D grid with
/// `dx ≠ dy` and different boundaries along x and y.
fn operators<T: Real>(bx: Boundary, by: Boundary) -> Vec<Box<dyn LinearOperator<T>>> {
    let g1 = Grid1::new(11, 0.3, 0.0, bx).unwrap();
    let g2 = Grid2::new(7, 5, 0.3, 0.45, bx)
        .unwrap()
        .with_boundaries(bx, by);
    let p = DiffusionParams::new(0.01, 0.5);
    vec![
        Box::new(Laplacian1::new(g1)),
        Box::new(Laplacian1::negative(g1).scaled(0.7)),
        Box::new(Laplacian2::new(g2)),
        Box::new(Laplacian2::negative(g2)),
        Box::new(Gradient1::new(g1)),
        Box::new(Gradient2::new(g2)),
        Box::new(Divergence1::new(g1)),
        Box::new(Divergence2::new(g2)),
        Box::new(ExplicitDiffusion1::new(g1, p).unwrap()),
        Box::new(ExplicitDiffusion2::new(g2, p).unwrap()),
    ]
}

fn dot_product_test_for_every_operator_and_boundary<T: Real>() {
    for (k, bx) in KINDS.into_iter().enumerate() {
        for (m, by) in KINDS.into_iter().enumerate() {
            for (i, a) in operators::<T>(bx, by).iter().enumerate() {
                let seed = (100 * k + 10 * m + i) as u64;
                let x = random_field::<T>(a.input_shape(), seed);
                let y = random_field::<T>(a.output_shape(), seed + 1000);
                let report = check_adjoint(
                    |v| a.apply(v).unwrap(),
                    |v| a.apply_transpose(v).unwrap(),
                    x.view(),
                    y.view(),
                )
                .unwrap();
                assert_adjoint_ok::<T>(&report);
            }
        }
    }
}

fn symmetric_operators_say_so_and_agree_with_their_triplets<T: Real>() {
    for bx in KINDS {
        for a in operators::<T>(bx, Boundary::Closed) {
            let x = random_field::<T>(a.input_shape(), 9);
            let ax = a.apply(x.view()).unwrap();
            let mut from_triplets = ArrayD::<T>::zeros(IxDyn(a.output_shape()));
            {
                let xs = x.as_slice().unwrap();
                let out = from_triplets.as_slice_mut().unwrap();
                for (r, c, v) in a.triplets().unwrap() {
                    out[r] += v * xs[c];
                }
            }
            assert_close(&from_triplets, &ax, a.name());
            if a.is_symmetric() {
                let aty = a.apply_transpose(x.view()).unwrap();
                assert_eq!(aty, ax, "{}", a.name());
            }
        }
    }
}

both_precisions!(
    dot_product_test_for_every_operator_and_boundary,
    symmetric_operators_say_so_and_agree_with_their_triplets
);

/// `max |(A f)(x_i) − g(x_i)|` over the cells of an `n × n` grid of [0, 1]².
fn laplacian_error(
    n: usize,
    b: Boundary,
    f: impl Fn(f64, f64) -> f64,
    lap: impl Fn(f64, f64) -> f64,
) -> f64 {
    let grid = Grid2::square(n, n, 1.0 / n as f64, b).unwrap();
    let at = |h: &dyn Fn(f64, f64) -> f64| {
        Array2::from_shape_fn((n, n), |(i, j)| {
            let c = grid.center(i, j);
            h(c[0], c[1])
        })
        .into_dyn()
    };
    let computed = Laplacian2::new(grid).apply(at(&f).view()).unwrap();
    max_abs_diff(&computed, &at(&lap))
}

#[test]
fn laplacian_converges_at_second_order_for_each_boundary() {
    use std::f64::consts::PI;
    // Each boundary with a field that satisfies it: periodic sin(2πx)sin(2πy);
    // zero Dirichlet sin(πx)sin(πy) (odd about the walls, zero on them); closed
    // cos(πx)cos(πy) (even about the walls, zero normal derivative). In all three
    // ∇²f = −k²f with k² = 8π², 2π², 2π².
    type Field = fn(f64, f64) -> f64;
    let cases: [(Boundary, f64, Field); 3] = [
        (Boundary::Periodic, 8.0 * PI * PI, |x, y| {
            (2.0 * PI * x).sin() * (2.0 * PI * y).sin()
        }),
        (Boundary::ZeroDirichlet, 2.0 * PI * PI, |x, y| {
            (PI * x).sin() * (PI * y).sin()
        }),
        (Boundary::Closed, 2.0 * PI * PI, |x, y| {
            (PI * x).cos() * (PI * y).cos()
        }),
    ];
    for (b, k2, f) in cases {
        let coarse = laplacian_error(16, b, f, |x, y| -k2 * f(x, y));
        let fine = laplacian_error(32, b, f, |x, y| -k2 * f(x, y));
        // Second order: halving h divides the error by about 4.
        let rate = (coarse / fine).log2();
        assert!(
            rate > 1.9 && rate < 2.1,
            "{b:?}: errors {coarse:e} → {fine:e}, rate {rate}"
        );
    }
}

#[test]
fn gradient_and_divergence_converge_at_second_order_inside() {
    use std::f64::consts::PI;
    let err = |n: usize| {
        let grid = Grid1::over(0.0, 1.0, n, Boundary::Periodic).unwrap();
        let x = Array1::from(grid.centers());
        let f = x.mapv(|x| (2.0 * PI * x).sin()).into_dyn();
        let df = x.mapv(|x| 2.0 * PI * (2.0 * PI * x).cos()).into_dyn();
        let g = Gradient1::new(grid).apply(f.view()).unwrap();
        let d = Divergence1::new(grid).apply(f.view()).unwrap();
        (max_abs_diff(&g, &df), max_abs_diff(&d, &df))
    };
    let ((g16, d16), (g32, d32)) = (err(16), err(32));
    assert!((g16 / g32).log2() > 1.9, "gradient {g16:e} → {g32:e}");
    assert!((d16 / d32).log2() > 1.9, "divergence {d16:e} → {d32:e}");
}

#[test]
fn divergence_of_gradient_is_the_wide_laplacian_and_minus_its_transpose() {
    // With closed walls Dᵀ = −G, so D G = −Gᵀ G is symmetric negative semidefinite.
    let grid = Grid2::new(6, 5, 0.2, 0.3, Boundary::Closed).unwrap();
    let (g, d) = (Gradient2::new(grid), Divergence2::new(grid));
    let x = random_field::<f64>(&[6, 5], 1);
    let dgx = d.apply(g.apply(x.view()).unwrap().view()).unwrap();
    let gtgx = g
        .apply_transpose(g.apply(x.view()).unwrap().view())
        .unwrap();
    assert_close(&dgx, &gtgx.mapv(|v| -v), "D G x vs −Gᵀ G x");
    let xdgx: f64 = x.iter().zip(&dgx).map(|(a, b)| a * b).sum();
    assert!(xdgx <= 0.0);
}

fn gradients_through_the_tape_adapter<T: Real>() {
    let grid = Grid2::new(5, 4, 0.3, 0.2, Boundary::ZeroDirichlet)
        .unwrap()
        .with_boundaries(Boundary::ZeroDirichlet, Boundary::Periodic);
    let lap = Arc::new(Laplacian2::negative(grid));
    let grad = Arc::new(Gradient2::new(grid));
    let x = random_field::<T>(&[5, 4], 4);
    // f(x) = ½ xᵀ(−∇²)x + Σ (Gᵀ G x)², ∂f/∂x = (−∇²) x + 4 GᵀG GᵀG x.
    assert_gradient(
        |tape, v| {
            let ax = tape.apply(LinearOp::new(Arc::clone(&lap)), &[v[0]])?;
            let gx = tape.apply(LinearOp::new(Arc::clone(&grad)), &[v[0]])?;
            let gtgx = tape.apply(LinearOp::transposed(Arc::clone(&grad)), &[gx])?;
            let half = tape.scalar(T::from_f64(0.5));
            v[0].dot(ax)?.mul(half)?.add(gtgx.dot(gtgx)?)
        },
        &[x],
    );
}

both_precisions!(gradients_through_the_tape_adapter);

#[test]
fn unstable_explicit_diffusion_is_refused() {
    let grid = Grid2::new(8, 8, 0.1, 0.1, Boundary::Periodic).unwrap();
    // ν·dt·(1/dx² + 1/dy²) = 0.1·0.05·200 = 1 > ½
    let p = DiffusionParams::new(0.1, 0.05);
    let err = ExplicitDiffusion2::new(grid, p).unwrap_err();
    assert!(err.to_string().contains("unstable"), "{err}");
}

// The unit tests of each stencil, moved from crates/ops/src/stencil: values by
// hand, the dot-product test with the triplets, and the boundary rules.

mod laplacian {
    use crate::common::check_operator_with_scale;
    use diffphys_ops::stencil::{Laplacian1, Laplacian2};
    use diffphys_ops::{Boundary, Grid1, Grid2, LinearOperator};
    use diffphys_tape::test_array;
    use ndarray::{arr1, arr2, ArrayD, IxDyn};

    const KINDS: [Boundary; 3] = [
        Boundary::Periodic,
        Boundary::ZeroDirichlet,
        Boundary::Closed,
    ];

    /// `A x` from the triplets, as a dense product.
    fn apply_triplets(t: &[(usize, usize, f64)], x: &ArrayD<f64>) -> Vec<f64> {
        let xs = x.as_slice().unwrap();
        let mut y = vec![0.0; xs.len()];
        for &(r, c, v) in t {
            y[r] += v * xs[c];
        }
        y
    }

    /// The shared checks, the triplets applied as a sparse product, the fused
    /// dot product and the diagonal.
    fn check_operator(a: &dyn LinearOperator<f64>, seed: u64, coef: f64) {
        check_operator_with_scale(a, seed, coef);
        let x = test_array::<f64>(a.input_shape(), seed);
        let ax = a.apply(x.view()).unwrap();
        let from_triplets = apply_triplets(&a.triplets().unwrap(), &x);
        for (p, q) in ax.iter().zip(&from_triplets) {
            assert!((p - q).abs() <= 1e-12 * (1.0 + p.abs()), "{p} vs {q}");
        }

        let mut out = ArrayD::zeros(IxDyn(a.output_shape()));
        let dot = a.apply_into_dot(x.view(), out.view_mut());
        // <x, A x> computed in the same pass agrees with the separate sum.
        let expect: f64 = x.iter().zip(&ax).map(|(p, q)| p * q).sum();
        assert!((dot - expect).abs() <= 1e-12 * expect.abs().max(1.0));
        assert_eq!(out, ax);

        let diag = a.diagonal().unwrap();
        let n = x.len();
        for (k, d) in diag.iter().enumerate() {
            let mut e = vec![0.0; n];
            e[k] = 1.0;
            let col = a
                .apply(
                    ArrayD::from_shape_vec(IxDyn(a.input_shape()), e)
                        .unwrap()
                        .view(),
                )
                .unwrap();
            assert!((col.as_slice().unwrap()[k] - d).abs() < 1e-12);
        }
    }

    #[test]
    fn one_d_stencil_values_by_boundary() {
        let x = arr1(&[1.0, 2.0, 4.0, 8.0]).into_dyn();
        let grid = |b| Grid1::new(4, 0.5, 0.0, b).unwrap();
        // 1/dx² = 4; interior cells: 4·(x₀ − 2x₁ + x₂) = 4·(1 − 4 + 4) = 4, 4·(2 − 8 + 8) = 8.
        let periodic = Laplacian1::new(grid(Boundary::Periodic))
            .apply(x.view())
            .unwrap();
        // wrap: 4·(8 − 2 + 2) = 32, 4·(4 − 16 + 1) = −44
        assert_eq!(periodic, arr1(&[32.0, 4.0, 8.0, -44.0]).into_dyn());
        let dirichlet = Laplacian1::new(grid(Boundary::ZeroDirichlet))
            .apply(x.view())
            .unwrap();
        // ghost −x: 4·(−1 − 2 + 2) = −4, 4·(4 − 16 − 8) = −80
        assert_eq!(dirichlet, arr1(&[-4.0, 4.0, 8.0, -80.0]).into_dyn());
        let closed = Laplacian1::negative(grid(Boundary::Closed))
            .scaled(0.5)
            .apply(x.view())
            .unwrap();
        // −½·: ghost +x: 4·(1 − 2 + 2) = 4, 4·(4 − 16 + 8) = −16
        assert_eq!(closed, arr1(&[-2.0, -2.0, -4.0, 8.0]).into_dyn());
    }

    #[test]
    fn two_d_stencil_on_a_non_square_grid() {
        // dx = 1, dy = 0.5: kx = 1, ky = 4.
        let grid = Grid2::new(2, 3, 1.0, 0.5, Boundary::Closed)
            .unwrap()
            .with_boundaries(Boundary::ZeroDirichlet, Boundary::Periodic);
        let x = arr2(&[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]).into_dyn();
        let ax = Laplacian2::new(grid).apply(x.view()).unwrap();
        // (0,0): x: (−1) − 2·1 + 4 = 1; y (wrap): 3 − 2 + 2 = 3 → 1 + 4·3 = 13
        // (0,1): x: −2 − 4 + 5 = −1; y: 1 − 4 + 3 = 0 → −1
        // (1,2): x: 3 − 12 − 6 = −15; y: 5 − 12 + 4 = −3 → −15 − 12 = −27
        assert_eq!(ax[[0, 0]], 13.0);
        assert_eq!(ax[[0, 1]], -1.0);
        assert_eq!(ax[[1, 2]], -27.0);
    }

    #[test]
    fn adjoint_triplets_dot_and_diagonal_for_every_boundary_1d() {
        for (k, b) in KINDS.into_iter().enumerate() {
            for n in [1, 2, 3, 7] {
                let g = Grid1::new(n, 0.3, 0.0, b).unwrap();
                // the centre coefficient 2/dx² bounds the others
                let coef = 2.0 / (0.3 * 0.3);
                check_operator(&Laplacian1::new(g), 10 * k as u64 + n as u64, coef);
                check_operator(
                    &Laplacian1::negative(g).scaled(2.5),
                    7 + n as u64,
                    2.5 * coef,
                );
            }
        }
    }

    #[test]
    fn adjoint_triplets_dot_and_diagonal_for_every_boundary_2d() {
        for (k, bx) in KINDS.into_iter().enumerate() {
            for (m, by) in KINDS.into_iter().enumerate() {
                for (nx, ny) in [(1, 1), (1, 4), (5, 1), (2, 2), (4, 7), (6, 3)] {
                    let g = Grid2::new(nx, ny, 0.7, 0.2, Boundary::Periodic)
                        .unwrap()
                        .with_boundaries(bx, by);
                    let seed = (100 * k + 10 * m + nx * ny) as u64;
                    let coef = 2.0 / (0.7 * 0.7) + 2.0 / (0.2 * 0.2);
                    check_operator(&Laplacian2::new(g), seed, coef);
                    check_operator(&Laplacian2::negative(g).scaled(0.3), seed + 3, 0.3 * coef);
                }
            }
        }
    }

    #[test]
    fn negative_laplacian_is_positive_definite_with_dirichlet_walls() {
        let g = Grid2::new(5, 4, 0.1, 0.3, Boundary::ZeroDirichlet).unwrap();
        let a = Laplacian2::negative(g);
        for seed in 0..5 {
            let x = test_array::<f64>(&[5, 4], seed);
            let mut out = ArrayD::zeros(IxDyn(&[5, 4]));
            assert!(a.apply_into_dot(x.view(), out.view_mut()) > 0.0);
        }
        // Periodic and closed: constants are in the kernel.
        for b in [Boundary::Periodic, Boundary::Closed] {
            let g = Grid2::new(5, 4, 0.1, 0.3, b).unwrap();
            let ones = ArrayD::<f64>::ones(IxDyn(&[5, 4]));
            let a1 = Laplacian2::negative(g).apply(ones.view()).unwrap();
            assert!(a1.iter().all(|v| v.abs() < 1e-10), "{b:?}");
        }
    }

    #[test]
    fn f32_matches_f64_and_strided_views_work() {
        let g = Grid2::new(6, 5, 0.5, 0.25, Boundary::Closed).unwrap();
        let a = Laplacian2::new(g);
        let x = test_array::<f64>(&[6, 5], 3);
        let ax = a.apply(x.view()).unwrap();
        let x32 = x.mapv(|v| v as f32);
        let ax32 = LinearOperator::<f32>::apply(&a, x32.view()).unwrap();
        for (p, q) in ax.iter().zip(&ax32) {
            assert!((p - f64::from(*q)).abs() < 1e-4 * (1.0 + p.abs()));
        }
        // A transposed (non-standard-layout) input of shape [6, 5].
        let xt = x.t().to_owned();
        let ax_t = a.apply(xt.t()).unwrap();
        assert_eq!(ax_t, ax);
        // A non-contiguous output view.
        let mut big = ArrayD::<f64>::zeros(IxDyn(&[5, 6]));
        a.apply_into(x.view(), big.view_mut().reversed_axes());
        assert_eq!(big.t(), ax);
    }
}

mod gradient {
    use crate::common::{check_operator, dense_of};
    use diffphys_ops::stencil::{Divergence2, Gradient1, Gradient2};
    use diffphys_ops::{Boundary, Grid1, Grid2, LinearOperator};
    use ndarray::arr1;

    const KINDS: [Boundary; 3] = [
        Boundary::Periodic,
        Boundary::ZeroDirichlet,
        Boundary::Closed,
    ];

    #[test]
    fn one_d_values_by_boundary() {
        let x = arr1(&[1.0, 2.0, 4.0, 8.0]).into_dyn();
        let g = |b| Gradient1::new(Grid1::new(4, 0.5, 0.0, b).unwrap());
        // 1/(2dx) = 1; interior: x₂ − x₀ = 3, x₃ − x₁ = 6.
        let p = g(Boundary::Periodic).apply(x.view()).unwrap();
        assert_eq!(p, arr1(&[2.0 - 8.0, 3.0, 6.0, 1.0 - 4.0]).into_dyn());
        let d = g(Boundary::ZeroDirichlet).apply(x.view()).unwrap();
        // ghosts −1 and −8: 2 + 1 = 3, −8 − 4 = −12
        assert_eq!(d, arr1(&[3.0, 3.0, 6.0, -12.0]).into_dyn());
        let c = g(Boundary::Closed).apply(x.view()).unwrap();
        // ghosts +1 and +8: 2 − 1 = 1, 8 − 4 = 4
        assert_eq!(c, arr1(&[1.0, 3.0, 6.0, 4.0]).into_dyn());
    }

    #[test]
    fn adjoint_and_triplets_for_every_boundary() {
        for (k, b) in KINDS.into_iter().enumerate() {
            for n in [1, 2, 3, 8] {
                check_operator(
                    &Gradient1::new(Grid1::new(n, 0.3, 0.0, b).unwrap()),
                    (10 * k + n) as u64,
                );
            }
            for (m, by) in KINDS.into_iter().enumerate() {
                for (nx, ny) in [(1, 1), (2, 5), (4, 3), (7, 6)] {
                    let grid = Grid2::new(nx, ny, 0.4, 0.15, b)
                        .unwrap()
                        .with_boundaries(b, by);
                    check_operator(&Gradient2::new(grid), (100 * k + 10 * m + nx) as u64);
                }
            }
        }
    }

    #[test]
    fn gradient_transpose_is_minus_divergence_for_periodic_and_closed() {
        for b in [Boundary::Periodic, Boundary::Closed] {
            let grid = Grid2::new(5, 4, 0.4, 0.15, b).unwrap();
            let g = dense_of(&Gradient2::new(grid));
            let d = dense_of(&Divergence2::new(grid));
            let diff = (&g.t() + &d).mapv(f64::abs).fold(0.0f64, |a, &b| a.max(b));
            assert!(diff < 1e-12, "{b:?}: {diff}");
        }
    }

    #[test]
    fn gradient_of_a_linear_field_is_exact_inside() {
        let grid = Grid2::new(6, 5, 0.5, 0.25, Boundary::Closed).unwrap();
        // x(i,j) = 3·x + 2·y at cell centres: ∂ₓ = 3, ∂ᵧ = 2 away from the walls.
        let f = ndarray::Array2::from_shape_fn((6, 5), |(i, j)| {
            let c = grid.center(i, j);
            3.0 * c[0] + 2.0 * c[1]
        })
        .into_dyn();
        let g = Gradient2::new(grid).apply(f.view()).unwrap();
        for i in 1..5 {
            for j in 1..4 {
                assert!((g[[0, i, j]] - 3.0).abs() < 1e-12);
                assert!((g[[1, i, j]] - 2.0).abs() < 1e-12);
            }
        }
    }
}

mod divergence {
    use crate::common::{check_operator, dense_of};
    use diffphys_ops::stencil::{Divergence1, Divergence2, Gradient1};
    use diffphys_ops::{Boundary, Grid1, Grid2, LinearOperator};
    use ndarray::arr1;

    const KINDS: [Boundary; 3] = [
        Boundary::Periodic,
        Boundary::ZeroDirichlet,
        Boundary::Closed,
    ];

    #[test]
    fn one_d_values_at_walls() {
        let v = arr1(&[1.0, 2.0, 4.0, 8.0]).into_dyn();
        let grid = Grid1::new(4, 0.5, 0.0, Boundary::Closed).unwrap();
        let d = Divergence1::new(grid).apply(v.view()).unwrap();
        // ghosts −1 and −8, 1/(2dx) = 1: 2 + 1 = 3, −8 − 4 = −12
        assert_eq!(d, arr1(&[3.0, 3.0, 6.0, -12.0]).into_dyn());
    }

    #[test]
    fn adjoint_and_triplets_for_every_boundary() {
        for (k, b) in KINDS.into_iter().enumerate() {
            for n in [1, 2, 3, 8] {
                check_operator(
                    &Divergence1::new(Grid1::new(n, 0.3, 0.0, b).unwrap()),
                    (10 * k + n) as u64,
                );
            }
            for (m, by) in KINDS.into_iter().enumerate() {
                for (nx, ny) in [(1, 1), (2, 5), (4, 3), (7, 6)] {
                    let grid = Grid2::new(nx, ny, 0.4, 0.15, b)
                        .unwrap()
                        .with_boundaries(b, by);
                    check_operator(&Divergence2::new(grid), (100 * k + 10 * m + nx) as u64);
                }
            }
        }
    }

    #[test]
    fn divergence_is_minus_gradient_transpose_in_1d() {
        for b in [Boundary::Periodic, Boundary::Closed] {
            let grid = Grid1::new(6, 0.25, 0.0, b).unwrap();
            let g = dense_of(&Gradient1::new(grid));
            let d = dense_of(&Divergence1::new(grid));
            assert_eq!(d, -g.t().to_owned(), "{b:?}");
        }
    }
}

mod diffusion {
    use diffphys_ops::stencil::{
        DiffusionParams, ExplicitDiffusion1, ExplicitDiffusion2, Laplacian1, Laplacian2,
    };
    use diffphys_ops::{Boundary, Grid1, Grid2, LinearOperator, OpsError};
    use diffphys_tape::{check_adjoint, test_array};
    use ndarray::ArrayD;

    #[test]
    fn diffusion_is_identity_plus_scaled_laplacian() {
        for b in [
            Boundary::Periodic,
            Boundary::ZeroDirichlet,
            Boundary::Closed,
        ] {
            let g = Grid2::new(5, 4, 0.5, 0.25, b).unwrap();
            let p = DiffusionParams::new(0.01, 0.1);
            let a = ExplicitDiffusion2::new(g, p).unwrap();
            let x = test_array::<f64>(&[5, 4], 1);
            let lap = Laplacian2::new(g).scaled(0.001).apply(x.view()).unwrap();
            let ax = a.apply(x.view()).unwrap();
            for ((p, l), x) in ax.iter().zip(&lap).zip(&x) {
                assert!((p - (x + l)).abs() < 1e-14);
            }
            let y = test_array::<f64>(&[5, 4], 2);
            let rep = check_adjoint(
                |v| a.apply(v).unwrap(),
                |v| a.apply_transpose(v).unwrap(),
                x.view(),
                y.view(),
            )
            .unwrap();
            assert!(rep.passes(1e-14));
            let d: ArrayD<f64> = a.diagonal().unwrap();
            // 1 − 2ν·dt·(1/dx² + 1/dy²) = 1 − 0.002·(4 + 16) = 0.96 inside
            assert!((d[[2, 2]] - 0.96).abs() < 1e-14);

            let g1 = Grid1::new(6, 0.5, 0.0, b).unwrap();
            let a1 = ExplicitDiffusion1::new(g1, p).unwrap();
            let x1 = test_array::<f64>(&[6], 3);
            let l1 = Laplacian1::new(g1).scaled(0.001).apply(x1.view()).unwrap();
            let a1x = a1.apply(x1.view()).unwrap();
            for ((p, l), x) in a1x.iter().zip(&l1).zip(&x1) {
                assert!((p - (x + l)).abs() < 1e-14);
            }
        }
    }

    #[test]
    fn unstable_steps_are_refused_unless_allowed() {
        let g = Grid1::new(8, 0.1, 0.0, Boundary::Periodic).unwrap();
        // ν·dt/dx² = 1·0.01/0.01 = 1 > ½
        let p = DiffusionParams::new(1.0, 0.01);
        assert!(matches!(
            ExplicitDiffusion1::new(g, p),
            Err(OpsError::InvalidArgument { .. })
        ));
        let allowed = DiffusionParams {
            allow_unstable: true,
            ..p
        };
        assert!(ExplicitDiffusion1::new(g, allowed).is_ok());
        assert!(ExplicitDiffusion1::new(g, DiffusionParams::new(-1.0, 0.01)).is_err());
        assert!(ExplicitDiffusion1::new(g, DiffusionParams::new(0.1, 0.0)).is_err());
    }
}

mod masked {
    use crate::common::{check_operator, dense_of};
    use diffphys_ops::stencil::{Gradient1, Gradient2, Laplacian2, Masked};
    use diffphys_ops::{Boundary, CellMask, Grid1, Grid2, LinearOperator};

    #[test]
    fn masked_laplacian_is_symmetric_with_identity_on_obstacles() {
        let grid = Grid2::new(6, 5, 0.2, 0.3, Boundary::Closed).unwrap();
        // A square obstacle in the middle.
        let mask = CellMask::from_fn2(&grid, |c| !(0.4..0.8).contains(&c[0]) || c[1] > 0.9);
        let m = Masked::new::<f64>(Laplacian2::negative(grid), mask.clone()).unwrap();
        check_operator(&m, 3);
        let dense = dense_of(&m);
        assert_eq!(dense, dense.t());
        let diag = LinearOperator::<f64>::diagonal(&m).unwrap();
        for (k, &a) in mask.as_slice().iter().enumerate() {
            assert_eq!(diag.as_slice().unwrap()[k], dense[[k, k]]);
            if !a {
                // An inactive row is the identity row.
                let row = dense.row(k);
                assert_eq!(row.sum(), 1.0);
            }
        }
    }

    #[test]
    fn non_square_or_wrong_mask_is_an_error() {
        let g = Grid1::new(4, 1.0, 0.0, Boundary::Periodic).unwrap();
        let g2 = Grid2::new(2, 3, 1.0, 1.0, Boundary::Periodic).unwrap();
        let wrong = CellMask::all_active(&[5]);
        assert!(Masked::new::<f64>(Gradient1::new(g), wrong).is_err());
        let grad2 = Gradient2::new(g2);
        assert!(Masked::new::<f64>(grad2, CellMask::all_active(&[2, 3])).is_err());
    }
}
