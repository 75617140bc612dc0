//! The multigrid V-cycle as the preconditioner of CG (MG-PCG) for every kind of
//! pressure system: zero Dirichlet, closed walls (null space), periodic, mixed,
//! open MAC boundaries and obstacle masks, at sizes that are not powers of two.
//! Symmetry of the cycle (dot-product test), its error reduction per cycle,
//! PCG iterations, gradients of the Poisson op and of the projection against
//! the exact (sparse Cholesky) ones, a finite-difference check of the Poisson
//! op with MG, and the typed errors.

mod common;

use std::sync::Arc;

use common::*;
use diffphys_ops::cg::{conjugate_gradient, CgError, CgParams, NullSpace, Preconditioner};
use diffphys_ops::mac::MacGrid;
use diffphys_ops::multigrid::Multigrid;
use diffphys_ops::poisson::PoissonSolve;
use diffphys_ops::projection::PressureProjection;
use diffphys_ops::reference::SparseCholesky;
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::{Boundary, CellMask, Grid2, LinearOperator, OpsError};
use ndarray::{ArrayD, IxDyn};

use Boundary::{Closed, Periodic, ZeroDirichlet};

/// The boundary pairs `(x, y)` of the Laplacian systems, with their null space.
const PAIRS: [(Boundary, Boundary); 6] = [
    (ZeroDirichlet, ZeroDirichlet),
    (Closed, Closed),
    (Periodic, Periodic),
    (ZeroDirichlet, Closed),
    (Periodic, Closed),
    (Periodic, ZeroDirichlet),
];

fn laplacian(nx: usize, ny: usize, (bx, by): (Boundary, Boundary)) -> (Laplacian2, NullSpace) {
    let grid = Grid2::new(nx, ny, 1.0 / nx as f64, 1.2 / nx as f64, bx)
        .unwrap()
        .with_boundaries(bx, by);
    let ns = if bx == ZeroDirichlet || by == ZeroDirichlet {
        NullSpace::None
    } else {
        NullSpace::Constant
    };
    (Laplacian2::negative(grid), ns)
}

/// Staggered grids with an obstacle (a disc and a corner block; the fluid
/// region stays connected), closed and open, plus a plain open one.
fn macs(nx: usize, ny: usize) -> Vec<(&'static str, MacGrid)> {
    let g = |bx, by| {
        Grid2::new(nx, ny, 1.0 / nx as f64, 1.0 / ny as f64, Closed)
            .unwrap()
            .with_boundaries(bx, by)
    };
    let obstacle = |grid: &Grid2| {
        CellMask::from_fn2(grid, |c| {
            let (x, y) = (c[0] - 0.4, c[1] - 0.55);
            x * x + y * y > 0.03 && !(c[0] > 0.75 && c[1] < 0.3)
        })
    };
    let (closed, open) = (g(Closed, Closed), g(ZeroDirichlet, Closed));
    vec![
        ("open", MacGrid::new(g(ZeroDirichlet, ZeroDirichlet))),
        (
            "masked-closed",
            MacGrid::with_mask(closed, obstacle(&closed)).unwrap(),
        ),
        (
            "masked-open",
            MacGrid::with_mask(open, obstacle(&open)).unwrap(),
        ),
    ]
}

fn norm(v: &ArrayD<f64>) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn rel_err(a: &ArrayD<f64>, b: &ArrayD<f64>) -> f64 {
    norm(&(a - b)) / norm(b)
}

/// A right-hand side in the operator's range: the mean over the active
/// cells removed for a null space (zero on inactive cells either way).
fn rhs(shape: [usize; 2], ns: &NullSpace, seed: u64) -> ArrayD<f64> {
    let mut b = random_field::<f64>(&shape, seed);
    match ns {
        NullSpace::None => {}
        NullSpace::Constant => {
            let mean = b.mean().unwrap();
            b.mapv_inplace(|v| v - mean);
        }
        NullSpace::ConstantOn(mask) => {
            mask.zero_inactive(b.view_mut()).unwrap();
            let mean = b.sum() / mask.active_count() as f64;
            for (v, &a) in b.iter_mut().zip(mask.as_slice()) {
                if a {
                    *v -= mean;
                }
            }
        }
        _ => unreachable!("no other null space here"),
    }
    b
}

/// MG-PCG iterations to relative residual `rtol`, and the true relative
/// residual reached.
fn pcg<A: LinearOperator<f64>>(a: &A, mg: Multigrid, ns: NullSpace, rtol: f64) -> (usize, f64) {
    let shape: [usize; 2] = a.input_shape().try_into().unwrap();
    let b = rhs(shape, &ns, 5);
    let params = CgParams::default()
        .with_rel_tol(rtol)
        .with_null_space(ns)
        .with_preconditioner(Preconditioner::Multigrid(Arc::new(mg)));
    let mut x = ArrayD::<f64>::zeros(IxDyn(&shape));
    let info = conjugate_gradient(a, b.view(), x.view_mut(), &params).unwrap();
    let r = &b - &a.apply(x.view()).unwrap();
    (info.iterations, norm(&r) / norm(&b))
}

#[test]
fn the_cycle_passes_the_dot_product_test_for_every_kind() {
    let check = |name: &str, mg: &Multigrid, shape: [usize; 2]| {
        let (x, y) = (
            random_field::<f64>(&shape, 2),
            random_field::<f64>(&shape, 3),
        );
        let report = check_adjoint(
            |v| LinearOperator::<f64>::apply(mg, v).unwrap(),
            |v| LinearOperator::<f64>::apply_transpose(mg, v).unwrap(),
            x.view(),
            y.view(),
        )
        .unwrap();
        // The transpose is the same cycle: this says <B x, y> = <x, B y>.
        assert!(report.passes(1e-12), "{name}: {report:?}");
    };
    for pair in PAIRS {
        // Odd sizes: a periodic axis of odd length breaks the checkerboard;
        // the reversed post-smoothing keeps the cycle symmetric anyway.
        let (a, _) = laplacian(45, 37, pair);
        let mg = Multigrid::new(a.grid(), 2).unwrap();
        assert!(mg.levels() >= 3);
        check(&format!("{pair:?}"), &mg, [45, 37]);
    }
    for (name, mac) in macs(45, 37) {
        check(name, &Multigrid::for_mac(&mac, 2).unwrap(), [45, 37]);
    }
}

/// The residual reduction of the stationary iteration `x ← x + B (b − A x)`
/// in its last of `cycles` cycles.
fn rate<A: LinearOperator<f64>>(a: &A, mg: &Multigrid, ns: &NullSpace, cycles: usize) -> f64 {
    let shape: [usize; 2] = a.input_shape().try_into().unwrap();
    let b = rhs(shape, ns, 4);
    let mut x = ArrayD::<f64>::zeros(IxDyn(&shape));
    let mut norms = Vec::new();
    for _ in 0..cycles {
        let r = &b - &a.apply(x.view()).unwrap();
        norms.push(norm(&r));
        x += &LinearOperator::<f64>::apply(mg, r.view()).unwrap();
    }
    norms[cycles - 1] / norms[cycles - 2]
}

#[test]
fn each_cycle_cuts_the_residual_by_a_bounded_factor() {
    for pair in PAIRS {
        for (nx, ny) in [(96, 80), (75, 61)] {
            let (a, ns) = laplacian(nx, ny, pair);
            let r = rate(&a, &Multigrid::new(a.grid(), 2).unwrap(), &ns, 8);
            // Measured 0.18–0.19 at every size and boundary.
            assert!(r < 0.25, "{pair:?} {nx}×{ny}: {r:.3} per cycle");
        }
    }
    for (name, mac) in macs(96, 80) {
        let a = mac.pressure_operator();
        let r = rate(
            &a,
            &Multigrid::for_mac(&mac, 2).unwrap(),
            &mac.null_space(),
            8,
        );
        // Obstacles: measured 0.87–0.90 (the cells an obstacle cuts are left
        // to the smoother: the coarse grids cover whole-fluid cells only).
        assert!(r < 0.95, "{name}: {r:.3} per cycle");
    }
}

#[test]
fn pcg_reaches_1e_8_in_few_iterations_for_every_kind_and_size() {
    for pair in PAIRS {
        for (nx, ny) in [(64, 64), (96, 80), (75, 61), (130, 34)] {
            let (a, ns) = laplacian(nx, ny, pair);
            let (k, reached) = pcg(&a, Multigrid::new(a.grid(), 2).unwrap(), ns, 1e-8);
            // Measured 7–10.
            assert!(
                k <= 12 && reached <= 1e-8,
                "{pair:?} {nx}×{ny}: {k} iterations, {reached:.2e}"
            );
        }
    }
    for (nx, ny) in [(64, 64), (75, 61)] {
        for (name, mac) in macs(nx, ny) {
            let mg = Multigrid::for_mac(&mac, 2).unwrap();
            let (k, reached) = pcg(&mac.pressure_operator(), mg, mac.null_space(), 1e-8);
            // Measured 8–11 open, 21–22 with the obstacle.
            assert!(
                k <= 25 && reached <= 1e-8,
                "{name} {nx}×{ny}: {k} iterations, {reached:.2e}"
            );
        }
    }
}

/// `∂L/∂b` of `L = ½‖A⁻¹ b − t‖²` through the Poisson op with MG-PCG, against
/// the exact gradient `A⁻¹ (A⁻¹ b − t)` (sparse Cholesky).
#[test]
fn poisson_gradient_with_multigrid_matches_the_exact_gradient_for_every_boundary() {
    for pair in PAIRS {
        let (nx, ny) = (45, 38);
        let (a, ns) = laplacian(nx, ny, pair);
        let exact = SparseCholesky::new(&a, ns.clone()).unwrap();
        let b = rhs([nx, ny], &ns, 7);
        let target = random_field::<f64>(&[nx, ny], 8);
        let p_exact = exact.solve(b.view()).unwrap();
        let g_exact = exact.solve((&p_exact - &target).view()).unwrap();

        let mg = Arc::new(Multigrid::new(a.grid(), 2).unwrap());
        let params = CgParams::default().with_rel_tol(1e-11).with_null_space(ns);
        let solve = PoissonSolve::new(Arc::new(a), params)
            .with_multigrid(mg)
            .unwrap();
        let log = solve.log();
        let tape = Tape::<f64>::new();
        let bv = tape.var(b.clone());
        let p = tape.apply(solve, &[bv]).unwrap();
        let d = p.sub(tape.constant(target.clone())).unwrap();
        let loss = d.mul(d).unwrap().sum().unwrap().mul_scalar(0.5).unwrap();
        let grads = tape.backward(loss, &[bv]).unwrap();
        let (ep, eg) = (
            rel_err(&p.to_array(), &p_exact),
            rel_err(grads.get(bv).unwrap(), &g_exact),
        );
        assert!(
            ep < 1e-9 && eg < 1e-9,
            "{pair:?}: p {ep:.2e}, grad {eg:.2e}"
        );
        let (f, adj) = (log.last_forward().unwrap(), log.last_adjoint().unwrap());
        assert!(
            f.iterations <= 15 && adj.iterations <= 15,
            "{pair:?}: {} + {} iterations",
            f.iterations,
            adj.iterations
        );
    }
}

/// The projection with MG-PCG on masked and open grids: pressure and
/// velocity gradient against the exact solves (the vjp's adjoint solve
/// `s = S(−D g_u − g_p)` with `S` the sparse Cholesky solve).
#[test]
fn masked_projection_with_multigrid_matches_the_exact_solves() {
    for (name, mac) in macs(37, 29) {
        let params = CgParams::default().with_rel_tol(1e-11);
        let proj = PressureProjection::new(mac.clone(), params)
            .with_multigrid(2)
            .unwrap();
        let exact = SparseCholesky::new(proj.operator(), mac.null_space()).unwrap();
        let ux = random_field::<f64>(&mac.shape_x(), 1);
        let uy = random_field::<f64>(&mac.shape_y(), 2);
        let out = proj.project(ux.view(), uy.view(), None).unwrap();
        let b = mac.divergence(ux.view(), uy.view()).unwrap().mapv(|v| -v);
        let p_exact = exact.solve(b.view()).unwrap();
        let ep = rel_err(&out.pressure, &p_exact);

        let gx = random_field::<f64>(&mac.shape_x(), 3);
        let gy = random_field::<f64>(&mac.shape_y(), 4);
        let grad = proj
            .project_vjp(Some(gx.view()), Some(gy.view()), None, None)
            .unwrap();
        let rhs = mac.divergence(gx.view(), gy.view()).unwrap().mapv(|v| -v);
        let s_exact = exact.solve(rhs.view()).unwrap();
        let es = rel_err(&grad.adjoint_pressure, &s_exact);
        assert!(ep < 1e-9 && es < 1e-9, "{name}: p {ep:.2e}, s {es:.2e}");
        assert!(
            out.info.iterations <= 30 && grad.info.iterations <= 30,
            "{name}: {} + {} iterations",
            out.info.iterations,
            grad.info.iterations
        );
    }
}

#[test]
fn poisson_op_with_multigrid_passes_the_finite_difference_check() {
    for pair in PAIRS {
        // 11 × 7 = 77 cells: two levels, the coarse one 6 × 4.
        let (a, ns) = laplacian(11, 7, pair);
        let mg = Arc::new(Multigrid::new(a.grid(), 2).unwrap());
        assert_eq!(mg.levels(), 2);
        let params = CgParams::default().with_rel_tol(1e-13).with_null_space(ns);
        let solve = PoissonSolve::new(Arc::new(a), params)
            .with_multigrid(mg)
            .unwrap();
        let b = random_field::<f64>(&[11, 7], 21);
        // L = Σ w ⊙ p² (w the checker's weight): nonlinear in p.
        assert_gradient(
            |t, v| {
                let p = t.apply(solve.clone(), &[v[0]])?;
                p.mul(p)
            },
            &[b],
        );
    }
}

#[test]
fn bad_shapes_sweeps_and_non_convergence_are_typed_errors() {
    let (a, ns) = laplacian(32, 24, (Closed, Closed));
    let other = Grid2::new(24, 32, 1.0, 1.0, Closed).unwrap();
    let wrong = Arc::new(Multigrid::new(&other, 2).unwrap());
    // Through the op's constructor…
    let err = PoissonSolve::<f64, _>::new(Arc::new(a.clone()), CgParams::default())
        .with_multigrid(Arc::clone(&wrong))
        .unwrap_err();
    assert!(matches!(err, OpsError::ShapeMismatch { .. }), "{err:?}");
    // …and through CG itself.
    let params = CgParams::default()
        .with_null_space(ns.clone())
        .with_preconditioner(Preconditioner::Multigrid(wrong));
    let b = rhs([32, 24], &ns, 1);
    let mut x = ArrayD::<f64>::zeros(IxDyn(&[32, 24]));
    let err = conjugate_gradient(&a, b.view(), x.view_mut(), &params).unwrap_err();
    assert!(matches!(err, CgError::ShapeMismatch { .. }), "{err:?}");

    let err = Multigrid::new(a.grid(), 0).unwrap_err();
    assert!(matches!(err, OpsError::InvalidArgument { .. }), "{err:?}");

    // Two MG-PCG iterations cannot reach 1e-12: NoConvergence, not a silent result.
    let mg = Arc::new(Multigrid::new(a.grid(), 2).unwrap());
    let params = CgParams::default()
        .with_rel_tol(1e-12)
        .with_max_iters(2)
        .with_null_space(ns)
        .with_preconditioner(Preconditioner::Multigrid(mg));
    let err = conjugate_gradient(&a, b.view(), x.view_mut(), &params).unwrap_err();
    assert!(
        matches!(err, CgError::NoConvergence { iterations: 2, .. }),
        "{err:?}"
    );
}
