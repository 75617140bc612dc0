//! Property tests on bad input, one per public op family: random grids and
//! boundaries, shapes that are right or off by one (or of another rank),
//! entries that may be NaN or infinite, velocities that may break the CFL
//! limit. Every op, recorded on a tape and swept back, must give a typed error
//! or a finite result: never a panic, never a NaN let through.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

use diffphys_ops::advection::{AdvectionParams, SemiLagrangian2, Upwind2};
use diffphys_ops::cg::{CgParams, NullSpace};
use diffphys_ops::mac::MacGrid;
use diffphys_ops::poisson::PoissonSolve;
use diffphys_ops::projection::{PressureProjection, ProjectionOp};
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::tape_ops::LinearOp;
use diffphys_ops::{Boundary, CellMask, Grid2};
use diffphys_tape::{ArrayD, IxDyn, Op, Tape, TapeError};

/// A small deterministic generator (SplitMix64), so a failing case is
/// reproducible from its number.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }
}

const CASES: u64 = 300;

/// `shape`, or (one time in three) a neighbour of it: a dimension off by one,
/// a dimension dropped or one added.
fn maybe_wrong(rng: &mut Rng, shape: &[usize]) -> Vec<usize> {
    let mut s = shape.to_vec();
    if rng.chance(2.0 / 3.0) {
        return s;
    }
    match rng.below(3) {
        0 => {
            let i = rng.below(s.len());
            s[i] = if rng.chance(0.5) || s[i] == 0 {
                s[i] + 1
            } else {
                s[i] - 1
            };
        }
        1 if s.len() > 1 => {
            s.pop();
        }
        _ => s.push(1 + rng.below(2)),
    }
    s
}

/// Entries of `scale · U(−1, 1)`, one in ten arrays with a NaN or an infinity.
fn array(rng: &mut Rng, shape: &[usize], scale: f64) -> ArrayD<f64> {
    let mut a = ArrayD::from_shape_fn(IxDyn(shape), |_| scale * (2.0 * rng.unit() - 1.0));
    if !a.is_empty() && rng.chance(0.1) {
        let i = rng.below(a.len());
        let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][rng.below(3)];
        a.as_slice_mut().unwrap()[i] = bad;
    }
    a
}

/// [`array`] of [`maybe_wrong`]`(shape)`.
fn field(rng: &mut Rng, shape: &[usize], scale: f64) -> ArrayD<f64> {
    let shape = maybe_wrong(rng, shape);
    array(rng, &shape, scale)
}

fn grid(rng: &mut Rng) -> Option<Grid2> {
    let b = |rng: &mut Rng| {
        [
            Boundary::ZeroDirichlet,
            Boundary::Closed,
            Boundary::Periodic,
        ][rng.below(3)]
    };
    let (nx, ny) = (1 + rng.below(9), 1 + rng.below(9));
    let mut g = Grid2::new(nx, ny, 1.0 / nx as f64, 1.0 / ny as f64, b(rng)).ok()?;
    g.boundary_y = b(rng);
    Some(g)
}

/// Records `op` on `inputs`, sums its outputs and sweeps back. `Ok(false)` if
/// the op refused (a typed error), `Ok(true)` if it ran; `Err` describes a
/// non-finite result that was let through.
fn run_op<O: Op<f64> + 'static>(op: O, inputs: &[ArrayD<f64>]) -> Result<bool, String> {
    let tape = Tape::<f64>::new();
    let vars: Vec<_> = inputs.iter().map(|a| tape.var(a.clone())).collect();
    let outs = match tape.apply_multi(op, &vars) {
        Ok(outs) => outs,
        Err(e) => return typed(e).map(|_| false),
    };
    let mut loss = tape.scalar(0.0);
    for out in &outs {
        if !out.value().iter().all(|v| v.is_finite()) {
            return Err(format!(
                "a non-finite output got through: {:?}",
                out.shape()
            ));
        }
        loss = match out.sum().and_then(|s| loss.add(s)) {
            Ok(l) => l,
            Err(e) => return typed(e).map(|_| false),
        };
    }
    match tape.backward(loss, &vars) {
        Ok(grads) => {
            for v in &vars {
                if let Some(g) = grads.get(*v) {
                    if !g.iter().all(|x| x.is_finite()) {
                        return Err("a non-finite gradient got through".into());
                    }
                }
            }
            Ok(true)
        }
        Err(e) => typed(e).map(|_| false),
    }
}

/// A typed error must say something.
fn typed(e: TapeError) -> Result<(), String> {
    if e.to_string().trim().is_empty() {
        Err(format!("an error without a message: {e:?}"))
    } else {
        Ok(())
    }
}

/// Runs `family` on `CASES` random cases; fails listing every case that
/// panicked or let a non-finite value through. Returns how many ran and how
/// many were refused, so a test can check both paths were taken.
fn fuzz(name: &str, family: impl Fn(&mut Rng) -> Option<Result<bool, String>>) -> (usize, usize) {
    let (mut ran, mut refused, mut failures) = (0, 0, Vec::new());
    for case in 0..CASES {
        let mut rng = Rng(case.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ name.len() as u64);
        match catch_unwind(AssertUnwindSafe(|| family(&mut rng))) {
            Ok(None) => {}
            Ok(Some(Ok(true))) => ran += 1,
            Ok(Some(Ok(false))) => refused += 1,
            Ok(Some(Err(why))) => failures.push(format!("case {case}: {why}")),
            Err(_) => failures.push(format!("case {case}: panicked")),
        }
    }
    assert!(failures.is_empty(), "{name}:\n{}", failures.join("\n"));
    (ran, refused)
}

fn both_paths(name: &str, (ran, refused): (usize, usize)) {
    assert!(
        ran > 0 && refused > 0,
        "{name}: {ran} ran, {refused} refused"
    );
}

#[test]
fn advection_gives_a_typed_error_or_a_finite_result() {
    let counts = fuzz("upwind2", |rng| {
        let g = grid(rng)?;
        let params = AdvectionParams::new(0.5 * g.dx.min(g.dy) * (0.5 + rng.unit()));
        let d = field(rng, &[g.nx, g.ny], 1.0);
        let speed = 2.0 * rng.unit();
        let u = field(rng, &[2, g.nx, g.ny], speed);
        Some(run_op(Upwind2::new(g, params), &[d, u]))
    });
    both_paths("upwind2", counts);
    let counts = fuzz("semi_lagrangian2", |rng| {
        let g = grid(rng)?;
        let dt = if rng.chance(0.1) {
            -0.1
        } else {
            0.05 + rng.unit()
        };
        let d = field(rng, &[g.nx, g.ny], 1.0);
        let u = field(rng, &[2, g.nx, g.ny], 3.0);
        Some(run_op(SemiLagrangian2::new(g, dt), &[d, u]))
    });
    both_paths("semi_lagrangian2", counts);
}

#[test]
fn stencils_and_solves_give_a_typed_error_or_a_finite_result() {
    let counts = fuzz("laplacian2", |rng| {
        let g = grid(rng)?;
        let x = field(rng, &[g.nx, g.ny], 1.0);
        Some(run_op(
            LinearOp::new(Arc::new(Laplacian2::negative(g))),
            &[x],
        ))
    });
    both_paths("laplacian2", counts);
    let counts = fuzz("poisson_solve", |rng| {
        let g = grid(rng)?;
        let singular = [g.boundary_x, g.boundary_y]
            .iter()
            .all(|b| *b != Boundary::ZeroDirichlet);
        let mut params = CgParams::default().with_rel_tol(1e-10);
        if singular && rng.chance(0.8) {
            params = params.with_null_space(NullSpace::Constant);
        }
        if rng.chance(0.15) {
            params = params.fixed_iterations(rng.below(3));
        }
        let mut b = field(rng, &[g.nx, g.ny], 1.0);
        if singular && b.iter().all(|v| v.is_finite()) && !b.is_empty() {
            let mean = b.mean().unwrap_or(0.0);
            b.mapv_inplace(|v| v - mean);
        }
        let solve = PoissonSolve::new(Arc::new(Laplacian2::negative(g)), params);
        Some(run_op(solve, &[b]))
    });
    both_paths("poisson_solve", counts);
}

#[test]
fn projection_gives_a_typed_error_or_a_finite_result() {
    let counts = fuzz("projection", |rng| {
        let g = grid(rng)?;
        let mac = if rng.chance(0.5) {
            let r = 0.1 + 0.3 * rng.unit();
            let mask =
                CellMask::from_fn2(&g, |[x, y]| (x - 0.5).powi(2) + (y - 0.5).powi(2) > r * r);
            MacGrid::with_mask(g, mask).ok()?
        } else {
            MacGrid::new(g)
        };
        let (sx, sy) = (mac.shape_x(), mac.shape_y());
        let ux = field(rng, &sx, 1.0);
        let uy = field(rng, &sy, 1.0);
        let projection = PressureProjection::new(mac, CgParams::default().with_rel_tol(1e-10));
        Some(run_op(ProjectionOp::new(Arc::new(projection)), &[ux, uy]))
    });
    both_paths("projection", counts);
}
