//! Conjugate gradient: manufactured solutions (`b = A x*`) in f32 and f64, with
//! and without Jacobi, singular operators, and every error provoked.

mod common;

use common::*;
use diffphys_ops::cg::{
    cg_solve, conjugate_gradient, CgError, CgParams, Identity, Jacobi, NullSpace, Preconditioner,
    Preconditioning, Structure,
};
use diffphys_ops::dense::DenseOperator;
use diffphys_ops::mac::{MacGrid, MacPoisson};
use diffphys_ops::reference::SparseCholesky;
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::{Boundary, Grid2, LinearOperator};
use diffphys_tape::{parallel, test_array};
use ndarray::{arr1, arr2, Array2, ArrayD, ArrayViewD, ArrayViewMutD, IxDyn};
use std::sync::Arc;

/// `‖x − x*‖ / ‖x*‖` in f64.
fn rel_err<T: Real>(x: &ArrayD<T>, x_star: &ArrayD<f64>) -> f64 {
    let num: f64 = x
        .iter()
        .zip(x_star)
        .map(|(a, b)| (a.as_f64() - b).powi(2))
        .sum();
    let den: f64 = x_star.iter().map(|b| b * b).sum();
    (num / den).sqrt()
}

fn cast<T: Real>(a: &ArrayD<f64>) -> ArrayD<T> {
    a.mapv(T::from_f64)
}

/// The tolerance each precision can meet on the true residual.
fn rel_tol<T: Real>() -> f64 {
    if T::EPS.as_f64() < 1e-10 {
        1e-10
    } else {
        1e-5
    }
}

/// Eigenvalues log-spaced from 1 to `kappa`.
fn log_spectrum(n: usize, kappa: f64) -> Vec<f64> {
    (0..n)
        .map(|i| kappa.powf(i as f64 / (n - 1) as f64))
        .collect()
}

/// Dense SPD matrix of condition 10³: the error obeys the perturbation bound
/// `‖x − x*‖/‖x*‖ ≤ κ·(‖b − A x‖/‖b‖ + ‖δA‖/‖A‖)`, with `δA` the rounding of
/// the matrix to `T` (at most ε per entry, so a few ε in norm).
fn manufactured_dense_spd<T: Real>() {
    let n = 40;
    let kappa = 1e3;
    let spectrum = log_spectrum(n, kappa);
    let a64 = DenseOperator::<f64>::with_spectrum(&spectrum, 7);
    let a = DenseOperator::<T>::with_spectrum(&spectrum, 7);
    let x_star = random_field::<f64>(&[n], 11);
    let b = a64.apply(x_star.view()).unwrap();
    for pre in [Preconditioning::None, Preconditioning::Jacobi] {
        let params = CgParams::default()
            .with_rel_tol(rel_tol::<T>())
            .with_preconditioner(pre.clone());
        let (x, info) = cg_solve(&a, cast::<T>(&b).view(), &params).unwrap();
        assert!(info.converged);
        let bound = kappa * (info.relative_residual.max(rel_tol::<T>()) + 8.0 * T::EPS.as_f64());
        let err = rel_err(&x, &x_star);
        assert!(
            err <= bound,
            "{} {pre:?}: error {err:.3e} > κ-bound {bound:.3e} ({info:?})",
            T::NAME
        );
        // CG on n unknowns: at most n steps in exact arithmetic, a few more here.
        assert!(info.iterations <= 2 * n, "{info:?}");
    }
}

/// The 2D Laplacian with zero Dirichlet walls, a random (rough) solution.
fn manufactured_laplacian<T: Real>() {
    let grid = Grid2::new(24, 20, 0.1, 0.05, Boundary::ZeroDirichlet).unwrap();
    let a = Laplacian2::negative(grid);
    let x_star = random_field::<f64>(&[24, 20], 5);
    let b = LinearOperator::<f64>::apply(&a, x_star.view()).unwrap();
    let exact = SparseCholesky::new(&a, NullSpace::None).unwrap();
    let x_ref = exact.solve(b.view()).unwrap();
    // faer's Cholesky reproduces x* to rounding: the reference is exact.
    assert!(rel_err(&x_ref, &x_star) < 1e-12);
    for pre in [Preconditioning::None, Preconditioning::Jacobi] {
        let params = CgParams::default()
            .with_rel_tol(rel_tol::<T>())
            .with_preconditioner(pre.clone())
            .with_history();
        let (x, info) = cg_solve(&a, cast::<T>(&b).view(), &params).unwrap();
        // κ(−∇²) on this grid is about 1.6·10³ (λ ∝ sin²); a rough x* sits in
        // the high modes, where the error is smaller than the residual.
        let limit = if T::EPS.as_f64() < 1e-10 { 1e-8 } else { 1e-3 };
        let err = rel_err(&x, &x_star);
        assert!(
            err < limit,
            "{} {pre:?}: {err:.3e} ({:?})",
            T::NAME,
            info.iterations
        );
        let h = info.history.as_ref().unwrap();
        assert_eq!(h.len(), info.iterations + 1);
        let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        // The first entry is ‖b‖ (zero initial guess), the last meets the tolerance.
        assert!(
            (h[0] - b_norm).abs() <= 1e-5 * b_norm,
            "{} vs {b_norm}",
            h[0]
        );
        assert!(*h.last().unwrap() <= rel_tol::<T>() * b_norm * (1.0 + 1e-6));
    }
}

both_precisions!(manufactured_dense_spd, manufactured_laplacian);

/// The stability study's floor, checked at the source: f32 CG on the 64×64 Laplacian to
/// relative tolerance 1e-5 lands within 1e-4 of the f64 exact solution (the
/// f64 accumulation of the dot products keeps it near 1e-6).
#[test]
fn f32_solution_on_64x64_is_within_1e_4_of_exact() {
    for boundary in [Boundary::ZeroDirichlet, Boundary::Closed] {
        let grid = Grid2::square(64, 64, 1.0 / 64.0, boundary).unwrap();
        let a = Laplacian2::negative(grid);
        let b = ArrayD::from_shape_fn(IxDyn(&[64, 64]), |ix| {
            let (x, y) = (ix[0] as f64 / 64.0, ix[1] as f64 / 64.0);
            (3.0 * x).sin() * (2.0 * y).cos() + x * y
        });
        let ns = if boundary == Boundary::Closed {
            NullSpace::Constant
        } else {
            NullSpace::None
        };
        let exact = SparseCholesky::new(&a, ns.clone())
            .unwrap()
            .solve(b.view())
            .unwrap();
        // 1e-5 lies at or below f32's rounding floor on this system: the
        // solve may stop there, flagged, but must not hit the cap.
        let params = CgParams::default()
            .with_rel_tol(1e-5)
            .with_null_space(ns)
            .with_require_convergence(false);
        let (x, info) = cg_solve(&a, cast::<f32>(&b).view(), &params).unwrap();
        assert!(!info.reached_cap(), "{info:?}");
        let err = rel_err(&x, &exact);
        assert!(err < 1e-4, "{boundary:?}: {err:.3e} after {info:?}");
    }
}

#[test]
fn jacobi_pays_off_on_a_badly_scaled_matrix() {
    // D A D with D spanning four decades: Jacobi undoes the scaling.
    let n = 60;
    let base = DenseOperator::<f64>::with_spectrum(&log_spectrum(n, 10.0), 3);
    let d: Vec<f64> = (0..n)
        .map(|i| 10f64.powf(4.0 * i as f64 / (n - 1) as f64 - 2.0))
        .collect();
    let m = base.matrix();
    let scaled = DenseOperator::new(Array2::from_shape_fn((n, n), |(i, j)| {
        let (p, q) = (i.min(j), i.max(j)); // the same rounding on both sides
        d[p] * m[[p, q]] * d[q]
    }));
    let x_star = random_field::<f64>(&[n], 2);
    let b = scaled.apply(x_star.view()).unwrap();
    let run = |pre| {
        let params = CgParams::default()
            .with_rel_tol(1e-10)
            .with_preconditioner(pre)
            .with_max_iters(100_000);
        cg_solve(&scaled, b.view(), &params).unwrap().1.iterations
    };
    let (plain, jacobi) = (run(Preconditioning::None), run(Preconditioning::Jacobi));
    assert!(
        3 * jacobi < plain,
        "Jacobi {jacobi} iterations vs {plain} without"
    );
}

#[test]
fn singular_neumann_system_with_the_mean_removed() {
    let grid = Grid2::new(16, 12, 1.0, 1.0, Boundary::Closed).unwrap();
    let a = Laplacian2::negative(grid);
    let mut x_star = random_field::<f64>(&[16, 12], 8);
    let mean = x_star.mean().unwrap();
    x_star.mapv_inplace(|v| v - mean);
    // b = A x* + 3: the constant is in the kernel's direction, not in the range;
    // the solver removes it and returns the zero-mean solution x*.
    let b = LinearOperator::<f64>::apply(&a, x_star.view()).unwrap() + 3.0;
    for pre in [Preconditioning::None, Preconditioning::Jacobi] {
        let params = CgParams::default()
            .with_rel_tol(1e-11)
            .with_null_space(NullSpace::Constant)
            .with_preconditioner(pre.clone());
        let (x, info) = cg_solve(&a, b.view(), &params).unwrap();
        assert!(rel_err(&x, &x_star) < 1e-8, "{pre:?} {info:?}");
        assert!(x.mean().unwrap().abs() < 1e-13);
        let reference = SparseCholesky::new(&a, NullSpace::Constant)
            .unwrap()
            .solve(b.view())
            .unwrap();
        assert!(rel_err(&x, &reference) < 1e-8);
    }
    // Without the null space the inconsistent system cannot be solved, and
    // the solver says so.
    let err = cg_solve(
        &a,
        b.view(),
        &CgParams::default().with_rel_tol(1e-11).with_max_iters(2000),
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            CgError::NotPositiveDefinite { .. } | CgError::NoConvergence { .. }
        ),
        "{err}"
    );
}

#[test]
fn warm_start_zero_rhs_layouts_and_fixed_iterations() {
    let grid = Grid2::new(12, 12, 1.0, 1.0, Boundary::ZeroDirichlet).unwrap();
    let a = Laplacian2::negative(grid);
    let b = random_field::<f64>(&[12, 12], 4);
    let params = CgParams::default().with_rel_tol(1e-10);
    let (x, info) = cg_solve(&a, b.view(), &params).unwrap();
    assert!(info.iterations > 5);

    // Starting from the solution: nothing to do.
    let mut warm = x.clone();
    let again = conjugate_gradient(&a, b.view(), warm.view_mut(), &params).unwrap();
    assert_eq!(again.iterations, 0);
    assert!(again.relative_residual <= 1e-10);

    // b = 0: x = 0 whatever the initial guess.
    let mut z = random_field::<f64>(&[12, 12], 9);
    let zero = ArrayD::<f64>::zeros(IxDyn(&[12, 12]));
    let info0 = conjugate_gradient(&a, zero.view(), z.view_mut(), &params).unwrap();
    assert_eq!(info0.iterations, 0);
    assert!(z.iter().all(|&v| v == 0.0));

    // A transposed (non-contiguous) solution view and right-hand side.
    let bt = b.t().to_owned();
    let mut xt = ArrayD::<f64>::zeros(IxDyn(&[12, 12]));
    conjugate_gradient(&a, bt.t(), xt.view_mut().reversed_axes(), &params).unwrap();
    assert!(max_abs_diff(&xt.t().to_owned(), &x) < 1e-12);

    // Fixed iteration counts: exactly k, no error, not converged.
    let (_, fixed) = cg_solve(&a, b.view(), &CgParams::default().fixed_iterations(3)).unwrap();
    assert_eq!(fixed.iterations, 3);
    assert!(!fixed.converged && fixed.relative_residual > 1e-3);

    // An absolute tolerance stops earlier than a tight relative one.
    let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    let (_, abs) = cg_solve(
        &a,
        b.view(),
        &CgParams::default()
            .with_rel_tol(0.0)
            .with_abs_tol(1e-3 * b_norm),
    )
    .unwrap();
    assert!(abs.residual_norm <= 1e-3 * b_norm && abs.iterations < info.iterations);
}

/// A symmetric operator whose product is NaN: recurrences must catch it.
struct Poisoned;

impl LinearOperator<f64> for Poisoned {
    fn name(&self) -> &str {
        "poisoned"
    }
    fn input_shape(&self) -> &[usize] {
        &[3]
    }
    fn output_shape(&self) -> &[usize] {
        &[3]
    }
    fn apply_into(&self, x: ArrayViewD<'_, f64>, mut out: ArrayViewMutD<'_, f64>) {
        out.assign(&x);
        out[0] = f64::NAN;
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, f64>, out: ArrayViewMutD<'_, f64>) {
        self.apply_into(y, out);
    }
    fn is_symmetric(&self) -> bool {
        true
    }
}

#[test]
fn every_error_is_provoked() {
    let spd = DenseOperator::new(arr2(&[[4.0, 1.0], [1.0, 3.0]]));
    let b = arr1(&[1.0, 2.0]).into_dyn();
    let p = CgParams::default();

    // NotPositiveDefinite: a mostly negative spectrum.
    let indefinite = DenseOperator::<f64>::with_spectrum(&[-3.0, -2.0, -1.0, 1.0], 5);
    let b4 = random_field::<f64>(&[4], 1);
    match cg_solve(&indefinite, b4.view(), &p).unwrap_err() {
        CgError::NotPositiveDefinite {
            iteration,
            curvature,
        } => assert!(curvature <= 0.0 && iteration < 4),
        e => panic!("expected NotPositiveDefinite, got {e}"),
    }
    // … and a negative diagonal, caught before iterating by Jacobi.
    let neg = DenseOperator::new(arr2(&[[-1.0, 0.0], [0.0, 1.0]]));
    let jacobi = CgParams::default().with_preconditioner(Preconditioning::Jacobi);
    assert_eq!(
        cg_solve(&neg, b.view(), &jacobi).unwrap_err(),
        CgError::NotPositiveDefinite {
            iteration: 0,
            curvature: -1.0
        }
    );

    // NoConvergence: five iterations cannot solve a 32×32 Laplacian to 1e-10;
    // x keeps the fifth iterate, the same as a fixed five-iteration run.
    let lap = Laplacian2::negative(Grid2::new(32, 32, 1.0, 1.0, Boundary::ZeroDirichlet).unwrap());
    let bl = random_field::<f64>(&[32, 32], 3);
    let mut x = ArrayD::zeros(IxDyn(&[32, 32]));
    let err = conjugate_gradient(
        &lap,
        bl.view(),
        x.view_mut(),
        &CgParams::default().with_rel_tol(1e-10).with_max_iters(5),
    )
    .unwrap_err();
    match &err {
        CgError::NoConvergence {
            iterations,
            residual,
            relative_residual,
            target,
        } => {
            assert_eq!(*iterations, 5);
            assert!(residual > target && *relative_residual > 1e-10);
        }
        e => panic!("expected NoConvergence, got {e}"),
    }
    assert!(err.to_string().contains("did not converge in 5 iterations"));
    let (x5, _) = cg_solve(&lap, bl.view(), &CgParams::default().fixed_iterations(5)).unwrap();
    assert!(max_abs_diff(&x, &x5) < 1e-12);

    // NonFinite: NaN in b, inf in the initial guess (x untouched), NaN from the
    // operator inside the recurrence.
    let mut nan_b = b.clone();
    nan_b[1] = f64::NAN;
    let mut x2 = arr1(&[0.5, 0.5]).into_dyn();
    let e = conjugate_gradient(&spd, nan_b.view(), x2.view_mut(), &p).unwrap_err();
    assert_eq!(
        e,
        CgError::NonFinite {
            iteration: 0,
            what: "the right-hand side b".to_string()
        }
    );
    assert_eq!(x2, arr1(&[0.5, 0.5]).into_dyn());
    let mut inf_x = arr1(&[f64::INFINITY, 0.0]).into_dyn();
    assert!(matches!(
        conjugate_gradient(&spd, b.view(), inf_x.view_mut(), &p),
        Err(CgError::NonFinite { iteration: 0, ref what }) if what.contains("initial guess")
    ));
    let e = cg_solve(&Poisoned, arr1(&[1.0, 1.0, 1.0]).into_dyn().view(), &p).unwrap_err();
    assert!(
        matches!(e, CgError::NonFinite { iteration: 0, ref what } if what.contains("curvature")),
        "{e}"
    );

    // Breakdown: in f32 a curvature of 1e-39 (subnormal) makes α overflow.
    let tiny = DenseOperator::new(arr2(&[[1e-39f32, 0.0], [0.0, 1.0]]));
    let e = cg_solve(
        &tiny,
        arr1(&[1.0f32, 0.0]).into_dyn().view(),
        &CgParams::default(),
    )
    .unwrap_err();
    assert!(
        matches!(e, CgError::Breakdown { iteration: 0, ref reason } if reason.contains("overflows f32")),
        "{e}"
    );

    // ShapeMismatch.
    let e = cg_solve(&spd, arr1(&[1.0, 2.0, 3.0]).into_dyn().view(), &p).unwrap_err();
    assert_eq!(
        e,
        CgError::ShapeMismatch {
            what: "right-hand side b".to_string(),
            expected: vec![2],
            found: vec![3]
        }
    );
    let mask = diffphys_ops::CellMask::all_active(&[3]);
    let e = cg_solve(
        &spd,
        b.view(),
        &p.clone().with_null_space(NullSpace::ConstantOn(mask)),
    )
    .unwrap_err();
    assert!(matches!(e, CgError::ShapeMismatch { .. }), "{e}");

    // InvalidArgument: not symmetric, not square, no diagonal for Jacobi, a
    // negative tolerance.
    let nonsym = DenseOperator::new(arr2(&[[1.0, 2.0], [0.0, 1.0]]));
    let e = cg_solve(&nonsym, b.view(), &p).unwrap_err();
    assert!(matches!(e, CgError::InvalidArgument { ref message } if message.contains("symmetric")));
    let rect = DenseOperator::new(arr2(&[[1.0, 2.0]]));
    assert!(matches!(
        cg_solve(&rect, arr1(&[1.0]).into_dyn().view(), &p),
        Err(CgError::InvalidArgument { .. })
    ));
    let e = cg_solve(&Poisoned, arr1(&[1.0, 1.0, 1.0]).into_dyn().view(), &jacobi).unwrap_err();
    assert!(matches!(e, CgError::InvalidArgument { ref message } if message.contains("diagonal")));
    assert!(matches!(
        cg_solve(&spd, b.view(), &CgParams::default().with_rel_tol(-1.0)),
        Err(CgError::InvalidArgument { .. })
    ));
}

#[test]
fn errors_display_their_context() {
    let e = CgError::NotPositiveDefinite {
        iteration: 3,
        curvature: -2.0,
    };
    assert!(e.to_string().contains("at iteration 3"));
    assert!(e.to_string().contains("null_space"));
    let e = CgError::ShapeMismatch {
        what: "right-hand side b".into(),
        expected: vec![2, 3],
        found: vec![3, 2],
    };
    assert!(e.to_string().contains("[3, 2]"));
}

/// Above the parallel threshold (150 × 130 cells, rows not a multiple of the
/// chunk, threshold lowered), a solve on one thread and on three gives bitwise the same
/// iterate, residual and iteration count, for the plain, the Jacobi and the
/// projected (closed walls) iteration; so does the stencil's fused dot.
#[test]
fn solves_are_bitwise_the_same_on_any_number_of_threads() {
    // Low enough for this grid to take the parallel path (results do not
    // depend on it; the tape's tests set the same value).
    parallel::set_min_parallel_len(2 * parallel::CHUNK);
    let (nx, ny) = (150, 130);
    let dirichlet = Grid2::new(nx, ny, 0.01, 0.02, Boundary::ZeroDirichlet).unwrap();
    let closed = Grid2::new(nx, ny, 0.01, 0.02, Boundary::Closed)
        .unwrap()
        .with_boundaries(Boundary::Closed, Boundary::Periodic);
    let b = test_array::<f64>(&[nx, ny], 5);
    let cases = [
        (Laplacian2::negative(dirichlet), CgParams::default()),
        (
            Laplacian2::negative(dirichlet),
            CgParams::default().with_preconditioner(Preconditioning::Jacobi),
        ),
        (
            Laplacian2::negative(closed),
            CgParams::default().with_null_space(NullSpace::Constant),
        ),
    ];
    for (a, params) in &cases {
        let params = params.clone().fixed_iterations(40);
        let run = || {
            let (x, info) = cg_solve(a, b.view(), &params).unwrap();
            let mut ax = ArrayD::zeros(b.raw_dim());
            let dot = a.apply_into_dot(x.view(), ax.view_mut());
            (x, info.iterations, info.relative_residual, dot, ax)
        };
        let one = parallel::with_threads(1, run);
        let three = parallel::with_threads(3, run);
        assert_eq!(one.1, three.1);
        assert_eq!(one.2.to_bits(), three.2.to_bits());
        assert_eq!(one.3.to_bits(), three.3.to_bits());
        let bits = |v: &ArrayD<f64>| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&one.0), bits(&three.0));
        assert_eq!(bits(&one.4), bits(&three.4));
        // The fused dot is <x, A x> to rounding.
        let plain: f64 = one.0.iter().zip(&one.4).map(|(x, y)| x * y).sum();
        assert!((one.3 - plain).abs() <= 1e-12 * plain.abs());
    }
}

/// Jacobi written by a user against [`Preconditioner`], in both precisions:
/// `1/diag` of the operator it was built for, declared diagonal (CG fuses
/// it) or not (CG calls `apply`).
#[derive(Debug)]
struct UserJacobi {
    inv32: Vec<f32>,
    inv64: Vec<f64>,
    declared: bool,
}

impl UserJacobi {
    fn new(diag: &ArrayD<f64>, declared: bool) -> Self {
        UserJacobi {
            inv32: diag.iter().map(|&d| 1.0 / d as f32).collect(),
            inv64: diag.iter().map(|&d| 1.0 / d).collect(),
            declared,
        }
    }
}

macro_rules! user_jacobi {
    ($t:ty, $inv:ident) => {
        impl Preconditioner<$t> for UserJacobi {
            fn name(&self) -> &str {
                "user_jacobi"
            }
            fn apply(&self, r: &[$t], z: &mut [$t]) {
                for ((z, &r), &d) in z.iter_mut().zip(r).zip(&self.$inv) {
                    *z = r * d;
                }
            }
            fn structure(&self) -> Structure<'_, $t> {
                if self.declared {
                    Structure::Diagonal(&self.$inv)
                } else {
                    Structure::General
                }
            }
        }
    };
}
user_jacobi!(f32, inv32);
user_jacobi!(f64, inv64);

/// Any preconditioner reaches CG through the one trait: a user's Jacobi
/// declared diagonal is the built-in Jacobi bit for bit (the same fused
/// pass), applied as a general preconditioner it takes the same iterations
/// to the same solution (to the rounding of separately summed dot
/// products), and the identity shared as a preconditioner is no
/// preconditioner, bit for bit.
fn user_preconditioners_go_through_the_trait<T: Real>() {
    let grid = Grid2::new(40, 30, 1.0 / 40.0, 1.0 / 30.0, Boundary::ZeroDirichlet).unwrap();
    let mask = diffphys_ops::CellMask::from_fn2(&grid, |c| {
        let (x, y) = (c[0] - 0.5, c[1] - 0.5);
        x * x + y * y > 0.04
    });
    let a = MacPoisson::new(MacGrid::with_mask(grid, mask).unwrap());
    let diag = LinearOperator::<f64>::diagonal(&a).unwrap();
    let b = random_field::<T>(&[40, 30], 4);
    let run = |pre: Preconditioning| {
        let params = CgParams::default()
            .with_rel_tol(rel_tol::<T>())
            .with_null_space(a.mac().null_space())
            .with_preconditioner(pre);
        cg_solve(&a, b.view(), &params).unwrap()
    };
    let bits = |x: &ArrayD<T>| x.iter().map(|v| v.as_f64().to_bits()).collect::<Vec<_>>();
    let (x_jacobi, info_jacobi) = run(Preconditioning::Jacobi);
    let (x_declared, info_declared) = run(Arc::new(UserJacobi::new(&diag, true)).into());
    assert_eq!(bits(&x_declared), bits(&x_jacobi));
    assert_eq!(info_declared, info_jacobi);
    let (x_general, info_general) = run(Arc::new(UserJacobi::new(&diag, false)).into());
    assert_eq!(info_general.iterations, info_jacobi.iterations);
    let x_ref = x_jacobi.mapv(|v| v.as_f64());
    assert!(rel_err(&x_general, &x_ref) < tol::<T>().close);
    let (x_none, info_none) = run(Preconditioning::None);
    let (x_identity, info_identity) = run(Arc::new(Identity).into());
    assert_eq!(bits(&x_identity), bits(&x_none));
    assert_eq!(info_identity, info_none);
    assert!(info_jacobi.iterations < info_none.iterations);
}
both_precisions!(user_preconditioners_go_through_the_trait);

#[test]
fn jacobi_is_typed_and_checks_its_operator() {
    let grid = Grid2::new(6, 5, 0.5, 0.25, Boundary::ZeroDirichlet).unwrap();
    let a = Laplacian2::negative(grid);
    let m = Jacobi::<f32>::new(&a).unwrap();
    assert_eq!(Preconditioner::<f32>::shape(&m), Some(&[6, 5][..]));
    // diag(−∇²) = 2/dx² + 2/dy² at an interior cell.
    let r = vec![1.0f32; 30];
    let mut z = vec![0.0f32; 30];
    m.apply(&r, &mut z);
    assert_eq!(z[6], 1.0 / (2.0 / 0.25 + 2.0 / 0.0625));
    assert_eq!(Preconditioner::<f32>::name(&m), "jacobi");
    assert!(matches!(
        Jacobi::<f64>::new(&DenseOperator::new(arr2(&[[1.0, 0.0], [0.0, -1.0]]))),
        Err(CgError::NotPositiveDefinite { .. })
    ));
}
