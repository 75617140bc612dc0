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
use diffphys_ops::cg::{conjugate_gradient, CgError, CgParams, NullSpace};
use diffphys_ops::mac::MacGrid;
use diffphys_ops::multigrid::Multigrid;
use diffphys_ops::poisson::PoissonSolve;
use diffphys_ops::projection::PressureProjection;
use diffphys_ops::reference::SparseCholesky;
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::{Boundary, CellMask, Grid2, LinearOperator, OpsError};
use diffphys_tape::test_array;
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
        .with_preconditioner(Arc::new(mg));
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
        // Obstacles: measured 0.21 (open, no obstacle), 0.66 and 0.40 (a
        // block, closed and open sides). Until the coarse levels kept the cut
        // cells (2026-11-26) it was 0.87–0.90.
        assert!(r < 0.75, "{name}: {r:.3} per cycle");
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
        .with_preconditioner(wrong);
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
        .with_preconditioner(mg);
    let err = conjugate_gradient(&a, b.view(), x.view_mut(), &params).unwrap_err();
    assert!(
        matches!(err, CgError::NoConvergence { iterations: 2, .. }),
        "{err:?}"
    );
}

#[test]
fn f32_mgpcg_past_convergence_is_converged_not_a_breakdown() {
    // On 3² cells the V-cycle solves almost exactly, so the f32 recurrence
    // residual falls by orders of magnitude per iteration until M⁻¹ r
    // underflows to 0 (‖r‖ ≈ 6e-43 after 5 iterations); a fixed count past
    // that point used to end in "CG broke down".
    let (a, ns) = laplacian(3, 3, (ZeroDirichlet, ZeroDirichlet));
    let b = rhs([3, 3], &ns, 5);
    let want = SparseCholesky::new(&a, ns.clone())
        .unwrap()
        .solve(b.view())
        .unwrap();
    let b32 = b.mapv(|v| v as f32);
    for k in [5, 10, 30, 300] {
        let params = CgParams::default()
            .with_preconditioner(Arc::new(Multigrid::new(a.grid(), 2).unwrap()))
            .fixed_iterations(k);
        let mut x = ArrayD::<f32>::zeros(IxDyn(&[3, 3]));
        let info = conjugate_gradient(&a, b32.view(), x.view_mut(), &params)
            .unwrap_or_else(|e| panic!("{k} iterations: {e}"));
        assert!(info.iterations <= k, "{info:?}");
        assert!(info.relative_residual < 1e-5, "{k}: {info:?}");
        let err = rel_err(&x.mapv(f64::from), &want);
        assert!(err < 1e-5, "{k} iterations: error {err:e}");
    }
}

// The cycle on Laplacians of stretched cells (aspect ratio 1.3), every
// boundary on each axis: symmetry, error reduction per cycle, MG-PCG
// iterations, sizes that cannot coarsen.

const KINDS: [Boundary; 3] = [ZeroDirichlet, Closed, Periodic];

/// A grid of `nx × ny` cells of aspect ratio 1.3 with boundaries `bx`, `by`.
fn stretched(nx: usize, ny: usize, bx: Boundary, by: Boundary) -> Grid2 {
    let mut g = Grid2::new(nx, ny, 1.0 / nx as f64, 1.3 / ny as f64, bx).unwrap();
    g.boundary_y = by;
    g
}

/// Removes the mean (summed in row-major order, as the cycle does).
fn remove_mean(b: &mut ArrayD<f64>) {
    let mean = b.iter().sum::<f64>() / b.len() as f64;
    b.iter_mut().for_each(|x| *x -= mean);
}

#[test]
fn the_cycle_is_symmetric_for_every_boundary() {
    for bx in KINDS {
        for by in KINDS {
            let mg = Multigrid::new(&stretched(32, 16, bx, by), 2).unwrap();
            assert!(mg.levels() >= 3);
            let (x, y) = (
                test_array::<f64>(&[32, 16], 2),
                test_array::<f64>(&[32, 16], 3),
            );
            let report = check_adjoint(
                |v| LinearOperator::<f64>::apply(&mg, v).unwrap(),
                |v| LinearOperator::<f64>::apply_transpose(&mg, v).unwrap(),
                x.view(),
                y.view(),
            )
            .unwrap();
            // Symmetric in fact, not only by declaration: <B x, y> = <x, B y>.
            assert!(report.passes(1e-12), "{bx:?} {by:?}: {report:?}");
        }
    }
}

/// The error reduction of the stationary iteration `x ← x + B (b − A x)`
/// per cycle, from the last of `cycles`.
fn grid_rate(g: &Grid2) -> f64 {
    let mg = Multigrid::new(g, 2).unwrap();
    let a = Laplacian2::negative(*g);
    let shape = [g.nx, g.ny];
    let mut b = test_array::<f64>(&shape, 4);
    if mg.is_singular() {
        remove_mean(&mut b);
    }
    let mut x = ArrayD::<f64>::zeros(IxDyn(&shape));
    let mut norms = Vec::new();
    for _ in 0..8 {
        let ax = LinearOperator::<f64>::apply(&a, x.view()).unwrap();
        let r = &b - &ax;
        norms.push(r.iter().map(|v| v * v).sum::<f64>().sqrt());
        let z = LinearOperator::<f64>::apply(&mg, r.view()).unwrap();
        x += &z;
    }
    norms[7] / norms[6]
}

#[test]
fn each_cycle_cuts_the_residual_by_a_size_independent_factor() {
    // Cells of aspect ratio 1.3 (a point smoother slows with anisotropy):
    // measured 0.18–0.19 per V(2,2) cycle at every size and boundary.
    for bx in KINDS {
        let r32 = grid_rate(&stretched(32, 32, bx, bx));
        let r512 = grid_rate(&stretched(512, 512, bx, bx));
        assert!(r32 < 0.25 && r512 < 0.25, "{bx:?}: {r32} {r512}");
        assert!(
            r512 - r32 < 0.02,
            "{bx:?}: the rate grows with size, {r32} → {r512}"
        );
    }
    // A size that is not a power of two (80 × 48 coarsens to 10 × 6), with
    // cells of aspect ratio 2.2: measured 0.33.
    assert!(
        grid_rate(&stretched(
            80,
            48,
            Boundary::ZeroDirichlet,
            Boundary::Closed
        )) < 0.4
    );
}

/// Iterations of the project's CG, preconditioned by the cycle, to relative
/// residual `rtol`, and the true relative residual reached.
fn grid_pcg(g: &Grid2, rtol: f64) -> (usize, f64) {
    let mg = Arc::new(Multigrid::new(g, 2).unwrap());
    let a = Laplacian2::negative(*g);
    let mut b = test_array::<f64>(&[g.nx, g.ny], 5);
    let mut params = CgParams::default()
        .with_rel_tol(rtol)
        .with_preconditioner(mg.clone());
    if mg.is_singular() {
        remove_mean(&mut b);
        params.null_space = NullSpace::Constant;
    }
    let mut x = ArrayD::<f64>::zeros(IxDyn(&[g.nx, g.ny]));
    let info = conjugate_gradient(&a, b.view(), x.view_mut(), &params).unwrap();
    let r = &b - &LinearOperator::<f64>::apply(&a, x.view()).unwrap();
    let norm = |v: &ArrayD<f64>| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    (info.iterations, norm(&r) / norm(&b))
}

#[test]
fn preconditioned_cg_reaches_1e_8_in_few_iterations_at_any_size_and_boundary() {
    for bx in KINDS {
        for n in [32, 64, 256] {
            let g = Grid2::new(n, n, 1.0 / n as f64, 1.0 / n as f64, bx).unwrap();
            let (k, reached) = grid_pcg(&g, 1e-8);
            assert!(
                k <= 15 && reached <= 1e-8,
                "{bx:?} {n}²: {k} iterations, {reached:e}"
            );
        }
    }
    // Mixed walls and a size that is not a power of two.
    let (k, reached) = grid_pcg(
        &stretched(80, 48, Boundary::Closed, Boundary::ZeroDirichlet),
        1e-8,
    );
    assert!(
        k <= 20 && reached <= 1e-8,
        "80×48: {k} iterations, {reached:e}"
    );
}

#[test]
fn sizes_that_do_not_coarsen_are_an_error() {
    // One cell across: the long axis cannot be halved with the other.
    let g = Grid2::new(5000, 1, 1.0, 1.0, Boundary::ZeroDirichlet).unwrap();
    let err = Multigrid::new(&g, 2).unwrap_err();
    assert!(err.to_string().contains("coarsens only to"), "{err}");
    assert!(Multigrid::new(&stretched(16, 16, Boundary::Closed, Boundary::Closed), 0).is_err());
}

/// As CG's preconditioner the cycle computes in f64 whatever the vectors'
/// precision: on `f32` vectors it is the `f64` cycle (applied in place) of
/// the widened input, rounded once; on `f64` vectors it is the cycle that the
/// operator view applies, bit for bit.
#[test]
fn the_preconditioner_is_the_f64_cycle_in_either_precision() {
    use diffphys_ops::cg::Preconditioner;
    for (name, mac) in macs(45, 37) {
        let mg = Multigrid::for_mac(&mac, 2).unwrap();
        assert_eq!(Preconditioner::<f32>::shape(&mg), Some(&[45, 37][..]));
        let r32 = random_field::<f32>(&[45, 37], 9);
        let r64 = r32.mapv(f64::from);
        let mut z32 = vec![0.0f32; 45 * 37];
        let mut z64 = vec![0.0f64; 45 * 37];
        Preconditioner::<f32>::apply(&mg, r32.as_slice().unwrap(), &mut z32);
        Preconditioner::<f64>::apply(&mg, r64.as_slice().unwrap(), &mut z64);
        let rounded: Vec<u32> = z64.iter().map(|&v| (v as f32).to_bits()).collect();
        let got: Vec<u32> = z32.iter().map(|v| v.to_bits()).collect();
        assert_eq!(got, rounded, "{name}");
        let view = LinearOperator::<f64>::apply(&mg, r64.view()).unwrap();
        let same = view
            .iter()
            .zip(&z64)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same, "{name}");
    }
}

/// MG-PCG on the pressure operator with an obstacle (a cylinder, a box), walls
/// closed and with an open side: iterations to a relative residual of 1e-8 at
/// 64² and 128² (issue 23 asks ≤ 12; McAdams et al. 2010 report about a 10×
/// residual reduction per two iterations with obstacles). Larger grids are
/// measured by `benches/multigrid.rs`.
///
/// Until 2026-11-26 the coarse levels left out every cell an obstacle cut and
/// the cycle took 15–19 iterations at 64² and 21–25 at 128²; with the cut
/// cells on the coarse levels it takes 8–10.
#[test]
fn mgpcg_with_obstacles_converges_in_a_dozen_iterations() {
    let cylinder = |c: [f64; 2]| (c[0] - 0.4).powi(2) + (c[1] - 0.5).powi(2) > 0.15f64.powi(2);
    let boxed = |c: [f64; 2]| !((0.3..0.6).contains(&c[0]) && (0.35..0.55).contains(&c[1]));
    let mut report = Vec::new();
    for n in [64, 128] {
        for (sides, bx) in [("closed", Closed), ("open", ZeroDirichlet)] {
            let grid = Grid2::new(n, n, 1.0 / n as f64, 1.0 / n as f64, Closed)
                .unwrap()
                .with_boundaries(bx, Closed);
            for (shape, fluid) in [
                ("cylinder", &cylinder as &dyn Fn([f64; 2]) -> bool),
                ("box", &boxed),
            ] {
                let mac = MacGrid::with_mask(grid, CellMask::from_fn2(&grid, fluid)).unwrap();
                let params = CgParams::default().with_rel_tol(1e-8);
                let proj = PressureProjection::new(mac.clone(), params)
                    .with_multigrid(2)
                    .unwrap();
                let ux = random_field::<f64>(&mac.shape_x(), 11);
                let uy = random_field::<f64>(&mac.shape_y(), 12);
                let out = proj.project(ux.view(), uy.view(), None).unwrap();
                report.push((n, sides, shape, out.info.iterations));
            }
        }
    }
    println!("{report:?}");
    let worst = report.iter().map(|r| r.3).max().unwrap();
    assert!(worst <= 12, "MG-PCG iterations to 1e-8: {report:?}");
}

/// A channel: closed side walls, its left end closed (a prescribed inflow:
/// zero Neumann for the pressure) and its right end open (zero Dirichlet),
/// a cylinder in it. The pressure operator has no wall term at the closed
/// end and one at the open end, and the cycle built from the same faces
/// preconditions it better than one that takes the closed end for open (what
/// the flow crate built before): measured 12, 16, 20 MG-PCG iterations to
/// 1e-8 at 32, 64, 128 cells across against 22, 30, 42. The count still grows
/// with the grid here: the coarse levels put the zero of an open face half a
/// coarse cell beyond the boundary, farther out on each level, and with one
/// open end the smoothest mode feels it.
#[test]
fn a_channel_closed_at_its_inflow_end() {
    let cylinder = |c: [f64; 2]| (c[0] - 0.5).powi(2) + (c[1] - 0.5).powi(2) > 0.1f64.powi(2);
    let mut report = Vec::new();
    for n in [32, 64, 128] {
        let h = 1.0 / n as f64;
        let grid = Grid2::new(2 * n, n, h, h, Closed)
            .unwrap()
            .with_boundaries(ZeroDirichlet, Closed);
        let both_open = MacGrid::with_mask(grid, CellMask::from_fn2(&grid, cylinder)).unwrap();
        let mac = both_open.clone().with_closed_side(0, false).unwrap();
        assert!(both_open.clone().with_closed_side(2, false).is_err());
        let ones = ArrayD::<f64>::ones(IxDyn(&[2 * n, n]));
        let a1 = LinearOperator::<f64>::apply(&mac.pressure_operator(), ones.view()).unwrap();
        assert!(a1[[0, 3]].abs() < 1e-9, "closed end: {}", a1[[0, 3]]);
        assert!((a1[[2 * n - 1, 3]] - 1.0 / (h * h)).abs() < 1e-6 / (h * h));
        let ux = random_field::<f64>(&mac.shape_x(), 21);
        let uy = random_field::<f64>(&mac.shape_y(), 22);
        let iterations = |cycle_of: &MacGrid| {
            let mg = Multigrid::for_mac(cycle_of, 2).unwrap();
            let params = CgParams::default()
                .with_rel_tol(1e-8)
                .with_preconditioner(Arc::new(mg));
            let out = PressureProjection::new(mac.clone(), params)
                .project(ux.view(), uy.view(), None)
                .unwrap();
            out.info.iterations
        };
        report.push((n, iterations(&mac), iterations(&both_open)));
    }
    println!("{report:?}");
    for &(n, matched, mismatched) in &report {
        assert!(matched < mismatched, "{n}: {report:?}");
    }
    assert!(report[0].1 <= 12, "{report:?}");
}

/// The cycle on all cores gives the serial cycle's bits: the parallel
/// red–black sweep updates each colour from the same values as the serial
/// one, and the parallel restriction adds in the serial order. Every
/// boundary pair, odd sizes (a periodic axis of odd length sweeps serially),
/// and the masked grids; the split length lowered so that these small levels
/// split into many blocks.
#[test]
fn the_cycle_gives_the_same_bits_on_any_number_of_threads() {
    diffphys_tape::parallel::set_min_parallel_len(1024);
    let bits = |v: &ArrayD<f64>| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let mut failed: Vec<String> = Vec::new();
    let mut check = |name: &str, mg: &Multigrid, shape: [usize; 2]| {
        let r = test_array::<f64>(&shape, 7);
        let apply = || LinearOperator::<f64>::apply(mg, r.view()).unwrap();
        let one = diffphys_tape::parallel::with_threads(1, apply);
        let three = diffphys_tape::parallel::with_threads(3, apply);
        assert!(one.iter().all(|v| v.is_finite()), "{name}");
        let (a, b) = (bits(&one), bits(&three));
        let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
        if differ > 0 {
            failed.push(format!("{name}: {differ} cells"));
        }
    };
    for (nx, ny) in [(96, 80), (75, 61)] {
        for pair in PAIRS {
            let (a, _) = laplacian(nx, ny, pair);
            let grid = *a.grid();
            let mg = Multigrid::new(&grid, 2).unwrap();
            check(&format!("{nx}x{ny} {pair:?}"), &mg, [nx, ny]);
        }
        for (name, mac) in macs(nx, ny) {
            let mg = Multigrid::for_mac(&mac, 2).unwrap();
            check(&format!("{nx}x{ny} {name}"), &mg, [nx, ny]);
        }
    }
    assert!(failed.is_empty(), "1 and 3 threads differ: {failed:?}");
}
