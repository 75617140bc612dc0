//! The variable-coefficient Laplacian `−∇·(k ∇x)` and its Poisson solve with the
//! conductivity `k` as a tape input: the operator's adjoint and sparse form, the
//! gradients in `b` and `k` against finite differences and against the exact
//! (sparse Cholesky) gradient, and bad input as typed errors.

mod common;

use common::*;
use diffphys_ops::cg::{CgParams, NullSpace};
use diffphys_ops::conductivity::{conductivity_solve, Conductivity2, ConductivitySolve};
use diffphys_ops::reference::SparseCholesky;
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::{Boundary, Grid2, LinearOperator, OpsError};
use ndarray::{Array2, ArrayD, Ix2};

/// Definite (zero-Dirichlet walls), singular (closed walls) and mixed (closed
/// in x, Dirichlet in y) grids, with the null space each needs.
fn grids(nx: usize, ny: usize) -> Vec<(Grid2, NullSpace)> {
    let g = |b| Grid2::new(nx, ny, 0.5, 0.25, b).unwrap();
    vec![
        (g(Boundary::ZeroDirichlet), NullSpace::None),
        (g(Boundary::Closed), NullSpace::Constant),
        (
            g(Boundary::Closed).with_boundaries(Boundary::Closed, Boundary::ZeroDirichlet),
            NullSpace::None,
        ),
    ]
}

/// A conductivity in `[0.5, 2]`, varying from cell to cell.
fn conductivity<T: Real>(shape: &[usize], seed: u64) -> ArrayD<T> {
    random_field::<f64>(shape, seed).mapv(|r| T::from_f64(1.25 + 0.75 * r))
}

fn as2<T: Real>(a: &ArrayD<T>) -> Array2<T> {
    a.clone().into_dimensionality::<Ix2>().unwrap()
}

fn operator_passes_the_dot_product_test_and_matches_its_triplets<T: Real>() {
    for (grid, _) in grids(6, 5) {
        let k = as2(&conductivity::<T>(&[6, 5], 1));
        let a = Conductivity2::new(grid, k.view()).unwrap();
        let x = random_field::<T>(&[6, 5], 2);
        let y = random_field::<T>(&[6, 5], 3);
        let report = check_adjoint(
            |v| a.apply(v).unwrap(),
            |v| a.apply_transpose(v).unwrap(),
            x.view(),
            y.view(),
        )
        .unwrap();
        assert_adjoint_ok::<T>(&report);
        // The sparse form (what the exact reference factors) is the same matrix.
        let ax = a.apply(x.view()).unwrap();
        let mut from_triplets = ArrayD::<f64>::zeros(ax.raw_dim());
        let xs = x.as_slice().unwrap();
        for (r, c, v) in LinearOperator::<T>::triplets(&a).unwrap() {
            from_triplets.as_slice_mut().unwrap()[r] += v.as_f64() * xs[c].as_f64();
        }
        assert_close(&ax, &from_triplets.mapv(T::from_f64), "triplets");
        // The fused curvature <x, A x> and the diagonal.
        let mut out = ArrayD::zeros(ax.raw_dim());
        let dot = a.apply_into_dot(x.view(), out.view_mut());
        let expect: f64 = x
            .iter()
            .zip(&ax)
            .map(|(p, q)| p.as_f64() * q.as_f64())
            .sum();
        assert!(
            (dot - expect).abs() <= tol::<T>().close * expect.abs(),
            "{dot} vs {expect}"
        );
        assert!(dot > 0.0);
        let e0 = ArrayD::from_shape_fn(ax.raw_dim(), |ix| {
            T::from_f64(f64::from(u8::from(ix[0] == 2 && ix[1] == 3)))
        });
        let col = a.apply(e0.view()).unwrap();
        assert_eq!(
            LinearOperator::<T>::diagonal(&a).unwrap()[[2, 3]],
            col[[2, 3]]
        );
    }
}

both_precisions!(operator_passes_the_dot_product_test_and_matches_its_triplets);

/// Both gradients of `L = ½‖p − t‖²` (and of `Σ w ⊙ p`) through two chained
/// solves against central finite differences, on every kind of grid.
#[test]
fn gradients_in_b_and_k_match_finite_differences() {
    for (grid, ns) in grids(5, 4) {
        let params = CgParams::default().with_rel_tol(1e-13).with_null_space(ns);
        let b = random_field::<f64>(&[5, 4], 4);
        let k = conductivity::<f64>(&[5, 4], 5);
        let t = random_field::<f64>(&[5, 4], 6);
        assert_gradient(
            |tape, v| {
                let solve = ConductivitySolve::new(grid, params.clone());
                let p = tape.apply(solve, &[v[0], v[1]])?;
                // A second solve with the same k feeds p back in: k enters twice.
                let q = tape.apply(ConductivitySolve::new(grid, params.clone()), &[p, v[1]])?;
                let d = q.sub(tape.constant(t.clone()))?;
                d.mul(d)?.sum()?.mul_scalar(0.5)
            },
            &[b.clone(), k.clone()],
        );
    }
}

/// At 24 × 20, `∂L/∂k` and `∂L/∂b` against the gradient from exact sparse
/// Cholesky solves of the same formula, and `∂L/∂k` along a direction against
/// a central difference of exact solves (independent of the formula).
#[test]
fn gradients_match_the_exact_gradient() {
    for (grid, ns) in grids(24, 20) {
        let b = random_field::<f64>(&[24, 20], 7);
        let k = as2(&conductivity::<f64>(&[24, 20], 8));
        let t = random_field::<f64>(&[24, 20], 9);
        let exact_op = |k: &Array2<f64>| {
            let a = Conductivity2::new(grid, k.view()).unwrap();
            let chol = SparseCholesky::new(&a, ns.clone()).unwrap();
            (a, chol)
        };
        let (a, chol) = exact_op(&k);
        let p = chol.solve(b.view()).unwrap();
        let lambda = chol.solve((&p - &t).view()).unwrap();
        let gk_exact = a
            .coefficient_vjp(p.view(), lambda.view())
            .unwrap()
            .mapv(|v| -v);
        let loss = |k: &Array2<f64>| {
            let p = exact_op(k).1.solve(b.view()).unwrap();
            0.5 * (&p - &t).mapv(|v| v * v).sum()
        };
        let dir = as2(&random_field::<f64>(&[24, 20], 10));
        let h = 1e-5;
        let fd = (loss(&(&k + &(&dir * h))) - loss(&(&k - &(&dir * h)))) / (2.0 * h);
        let along = (&gk_exact * &dir.clone().into_dyn()).sum();
        assert!(
            (fd - along).abs() <= 1e-7 * along.abs(),
            "fd {fd:e} vs {along:e}"
        );

        let params = CgParams::default()
            .with_rel_tol(1e-11)
            .with_null_space(ns.clone());
        let tape = Tape::<f64>::new();
        let (bv, kv) = (tape.var(b.clone()), tape.var(k.clone().into_dyn()));
        let solve = ConductivitySolve::new(grid, params);
        let log = solve.log();
        let pv = tape.apply(solve, &[bv, kv]).unwrap();
        let d = pv.sub(tape.constant(t.clone())).unwrap();
        let l = d.mul(d).unwrap().sum().unwrap().mul_scalar(0.5).unwrap();
        let grads = tape.backward(l, &[bv, kv]).unwrap();
        let rel = |g: &ArrayD<f64>, e: &ArrayD<f64>| {
            ((g - e).mapv(|v| v * v).sum() / e.mapv(|v| v * v).sum()).sqrt()
        };
        let (ek, eb) = (
            rel(grads.get(kv).unwrap(), &gk_exact),
            rel(grads.get(bv).unwrap(), &lambda),
        );
        assert!(ek < 1e-8 && eb < 1e-8, "{ns:?}: k {ek:.2e}, b {eb:.2e}");
        assert_eq!((log.forward_solves(), log.adjoint_solves()), (1, 1));
    }
}

/// With `k ≡ 1` the solve is the one of the constant-coefficient Laplacian.
#[test]
fn unit_conductivity_solves_the_poisson_equation() {
    use diffphys_ops::poisson::poisson_solve;
    use diffphys_ops::stencil::Laplacian2;
    let (grid, _) = grids(12, 10).remove(0);
    let b = random_field::<f64>(&[12, 10], 11);
    let ones = Array2::<f64>::ones((12, 10));
    let params = CgParams::default().with_rel_tol(1e-12);
    let (p, info) = conductivity_solve(grid, ones.view(), b.view(), &params).unwrap();
    assert!(info.converged);
    let (q, _) = poisson_solve(&Laplacian2::negative(grid), b.view(), &params).unwrap();
    assert!(max_abs_diff(&p, &q) < 1e-10 * q.iter().fold(0.0f64, |m, v| m.max(v.abs())));
}

#[test]
fn bad_conductivities_and_boundaries_are_typed_errors() {
    let grid = Grid2::new(4, 3, 0.5, 0.5, Boundary::ZeroDirichlet).unwrap();
    let mut k = Array2::<f64>::ones((4, 3));
    k[[2, 1]] = 0.0;
    let e = Conductivity2::new(grid, k.view()).unwrap_err();
    assert!(
        matches!(e, OpsError::InvalidArgument { ref message, .. } if message.contains("(2, 1)")),
        "{e}"
    );
    k[[2, 1]] = f64::NAN;
    assert!(matches!(
        Conductivity2::new(grid, k.view()),
        Err(OpsError::NonFinite { .. })
    ));
    let wrong = Array2::<f64>::ones((3, 4));
    assert!(matches!(
        Conductivity2::new(grid, wrong.view()),
        Err(OpsError::ShapeMismatch { .. })
    ));
    let periodic = Grid2::new(4, 3, 0.5, 0.5, Boundary::Periodic).unwrap();
    let e = Conductivity2::new(periodic, Array2::<f64>::ones((4, 3)).view()).unwrap_err();
    assert!(e.to_string().contains("periodic"), "{e}");

    // On the tape: an error named after the op, holding the cause.
    let tape = Tape::<f64>::new();
    let b = tape.var(ArrayD::ones(vec![4, 3]));
    let kv = tape.var(ArrayD::from_elem(vec![4, 3], -1.0));
    let e = tape
        .apply(ConductivitySolve::new(grid, CgParams::default()), &[b, kv])
        .unwrap_err();
    let text = e.to_string();
    assert!(
        text.contains("conductivity") && text.contains("positive"),
        "{text}"
    );
}

#[test]
fn unit_conductivity_is_the_negative_laplacian() {
    for b in [Boundary::ZeroDirichlet, Boundary::Closed] {
        let grid = Grid2::new(5, 4, 0.3, 0.2, b).unwrap();
        let ones = ndarray::Array2::<f64>::ones((5, 4));
        let a = Conductivity2::new(grid, ones.view()).unwrap();
        let x = diffphys_tape::test_array::<f64>(&[5, 4], 3);
        let want = Laplacian2::negative(grid).apply(x.view()).unwrap();
        let got = LinearOperator::<f64>::apply(&a, x.view()).unwrap();
        for (p, q) in got.iter().zip(&want) {
            assert!(
                (p - q).abs() <= 1e-12 * q.abs().max(1.0),
                "{b:?}: {p} vs {q}"
            );
        }
    }
}
