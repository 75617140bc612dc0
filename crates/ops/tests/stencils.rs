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
