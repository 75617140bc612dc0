//! The CG iteration: restarts, stopping, breakdown and curvature checks.

use std::borrow::Cow;

use diffphys_tape::Real;
use ndarray::{ArrayViewD, ArrayViewMutD, IxDyn};

use crate::LinearOperator;

use super::kernels::{
    axpy, dot, subtract_multiple, update_direction, update_residual, update_residual_jacobi,
    weighted_sum, Sums,
};
use super::params::{CgError, CgInfo, CgParams};
use super::preconditioner::{Applied, Preconditioner};
use crate::linear::NullSpace;

/// A restart needs the true residual above this multiple of its estimated
/// rounding floor. Measured on 64² Laplacians: when the recurrence converges in
/// `f32`, the true residual sits at 3–7 times the estimate, and a restart lowers
/// it to 1–2 times but leaves the error unchanged while costing 30–100% more
/// iterations; a drifting `f64` recurrence at a tolerance far above the floor
/// restarts.
const RESTART_ABOVE_FLOOR: f64 = 10.0;

/// Where an iteration sequence stopped.
pub(super) enum Stop {
    /// The recurrence residual met the tolerance.
    Converged,
    /// The iteration cap.
    Cap,
}

/// How a whole solve (iterations and restarts) ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Outcome {
    /// The true residual met the tolerance.
    Converged,
    /// The iteration cap.
    Cap,
    /// The recurrence met the tolerance, the true residual stalled above it and
    /// restarting could not help; the estimated relative rounding floor.
    Stalled(f64),
}

/// The working state of one solve: all vectors, allocated once.
pub(super) struct Solver<'a, T: Real, A: ?Sized> {
    op: &'a A,
    shape: Vec<usize>,
    params: &'a CgParams,
    max_iters: usize,
    r: Vec<T>,
    p: Vec<T>,
    q: Vec<T>,
    /// `M⁻¹ r` (empty without preconditioner: `z = r`).
    z: Vec<T>,
    /// `M⁻¹` of a diagonal preconditioner (Jacobi), fused into the residual
    /// update; empty otherwise.
    inv_d: Cow<'a, [T]>,
    /// The preconditioner that computes `z` by [`Preconditioner::apply`],
    /// if it is neither the identity nor diagonal.
    general: Option<&'a dyn Preconditioner<T>>,
    /// The null vector, `None` for the constants (or no null space).
    k: Option<Vec<T>>,
    /// `kᵀ k`; 0 without null space.
    kk: f64,
    iterations: usize,
    history: Option<Vec<f64>>,
    /// [`Self::rounding_floor`] of the iterate, computed once the recurrence
    /// residual has dropped below `ε` (see [`Self::stagnated`]).
    floor: Option<f64>,
}

impl<'a, T: Real, A: LinearOperator<T> + ?Sized> Solver<'a, T, A> {
    pub(super) fn new(op: &'a A, shape: Vec<usize>, params: &'a CgParams) -> Result<Self, CgError> {
        let n: usize = shape.iter().product();
        let (k, kk) = match &params.null_space {
            NullSpace::None => (None, 0.0),
            NullSpace::Constant => (None, n as f64),
            NullSpace::ConstantOn(mask) => (
                Some(
                    mask.as_slice()
                        .iter()
                        .map(|&a| if a { T::one() } else { T::zero() })
                        .collect(),
                ),
                mask.active_count() as f64,
            ),
        };
        let (z, inv_d, general) = match params.preconditioner.resolve(op, &shape)? {
            Applied::Identity => (Vec::new(), Cow::Borrowed(&[][..]), None),
            Applied::Diagonal(d) => (vec![T::zero(); n], d, None),
            Applied::General(m) => (vec![T::zero(); n], Cow::Borrowed(&[][..]), Some(m)),
        };
        let max_iters = params.max_iters.unwrap_or(2 * n + 10);
        Ok(Solver {
            op,
            shape,
            params,
            max_iters,
            r: vec![T::zero(); n],
            p: vec![T::zero(); n],
            q: vec![T::zero(); n],
            z,
            inv_d,
            general,
            k,
            kk,
            iterations: 0,
            history: params
                .record_history
                .then(|| Vec::with_capacity(max_iters.saturating_add(1).min(1 << 16))),
            floor: None,
        })
    }

    fn projecting(&self) -> bool {
        self.kk > 0.0
    }

    /// `y = A x` on slices, returning `<x, A x>` (in f64).
    fn apply(&self, x: &[T], y: &mut [T]) -> f64 {
        let xv = ArrayViewD::from_shape(IxDyn(&self.shape), x).expect("length matches shape");
        let yv = ArrayViewMutD::from_shape(IxDyn(&self.shape), y).expect("length matches shape");
        self.op.apply_into_dot(xv, yv)
    }

    /// `<Π r, Π r>` and `<Π r, Π z>` from the raw sums.
    fn projected(&self, s: Sums) -> (f64, f64) {
        if self.projecting() {
            (s.rr - s.kr * s.kr / self.kk, s.rz - s.kr * s.kz / self.kk)
        } else {
            (s.rr, s.rz)
        }
    }

    /// The mean of `z` along `k` that `Π` removes (0 without null space).
    fn z_mean(&self, s: Sums) -> T {
        if self.projecting() {
            T::from_f64(s.kz / self.kk)
        } else {
            T::zero()
        }
    }

    /// Whether `z = M⁻¹ r` differs from `r` (some preconditioner).
    fn preconditioned(&self) -> bool {
        !self.inv_d.is_empty() || self.general.is_some()
    }

    /// `z = M⁻¹ r` by the general preconditioner, then `<r, z>` and `<k, z>`
    /// into `sums`.
    fn general_sums(&mut self, mut sums: Sums) -> Sums {
        if let Some(m) = self.general {
            m.apply(&self.r, &mut self.z);
            let k = self.k.as_deref();
            sums.rz = dot(&self.r, &self.z);
            sums.kz = weighted_sum(&self.z, k);
        }
        sums
    }

    /// `z = M⁻¹ r` and the sums, from the current `r`.
    fn residual_sums(&mut self) -> Sums {
        if !self.preconditioned() {
            let k = self.k.as_deref();
            let rr = dot(&self.r, &self.r);
            let kr = if self.projecting() {
                weighted_sum(&self.r, k)
            } else {
                0.0
            };
            return Sums {
                rr,
                rz: rr,
                kr,
                kz: kr,
            };
        }
        if self.general.is_some() {
            let k = self.k.as_deref();
            let sums = Sums {
                rr: dot(&self.r, &self.r),
                rz: 0.0,
                kr: weighted_sum(&self.r, k),
                kz: 0.0,
            };
            return self.general_sums(sums);
        }
        for ((z, &r), &d) in self.z.iter_mut().zip(&self.r).zip(self.inv_d.iter()) {
            *z = r * d;
        }
        let k = self.k.as_deref();
        Sums {
            rr: dot(&self.r, &self.r),
            rz: dot(&self.r, &self.z),
            kr: weighted_sum(&self.r, k),
            kz: weighted_sum(&self.z, k),
        }
    }

    /// `p = Π z` from fresh sums: the first direction (and after a restart).
    fn first_direction(&mut self, s: Sums) {
        let m = self.z_mean(s);
        let z = if self.preconditioned() {
            &self.z
        } else {
            &self.r
        };
        self.p.copy_from_slice(z);
        if self.projecting() {
            subtract_multiple(&mut self.p, m, self.k.as_deref());
        }
    }

    /// `r = Π(b)/s − A x̂` (with `A x̂` skipped when `x̂ = 0`), then the sums.
    fn true_residual(
        &mut self,
        b: &ArrayViewD<'_, T>,
        b_mean: T,
        s: T,
        x: &[T],
        x_zero: bool,
    ) -> Sums {
        for (r, &bv) in self.r.iter_mut().zip(b.iter()) {
            *r = bv;
        }
        if self.projecting() {
            subtract_multiple(&mut self.r, b_mean, self.k.as_deref());
        }
        self.r.iter_mut().for_each(|r| *r /= s);
        if !x_zero {
            let mut q = std::mem::take(&mut self.q);
            self.apply(x, &mut q);
            self.r.iter_mut().zip(&q).for_each(|(r, &q)| *r -= q);
            self.q = q;
        }
        self.residual_sums()
    }

    /// Iterates from the direction in `p` until the recurrence residual meets
    /// `tol` or the cap. `rz` is `<Π r, Π z>` of the current residual.
    fn iterate(
        &mut self,
        x: &mut [T],
        mut rz: f64,
        tol: f64,
        b_norm: f64,
    ) -> Result<Stop, CgError> {
        let tol2 = tol * tol;
        while self.iterations < self.max_iters {
            let it = self.iterations;
            let mut q = std::mem::take(&mut self.q);
            let pq = self.apply(&self.p, &mut q);
            self.q = q;
            if !pq.is_finite() {
                return Err(CgError::non_finite(it, "the curvature <p, A p>"));
            }
            if pq <= 0.0 {
                return Err(CgError::NotPositiveDefinite {
                    iteration: it,
                    curvature: pq,
                });
            }
            let alpha = rz / pq;
            let alpha_t = T::from_f64(alpha);
            if !alpha_t.is_finite() {
                return Err(CgError::Breakdown {
                    iteration: it,
                    reason: format!(
                        "step length α = <r, z>/<p, A p> = {rz:e}/{pq:e} overflows {}",
                        T::NAME
                    ),
                });
            }
            let sums = {
                let k = self.k.as_deref();
                if self.general.is_some() {
                    let sums = update_residual(alpha_t, &self.q, &mut self.r, k);
                    self.general_sums(sums)
                } else if self.inv_d.is_empty() {
                    update_residual(alpha_t, &self.q, &mut self.r, k)
                } else {
                    update_residual_jacobi(
                        alpha_t,
                        &self.q,
                        &mut self.r,
                        &self.inv_d,
                        &mut self.z,
                        k,
                    )
                }
            };
            self.iterations += 1;
            let (rr, rz_new) = self.projected(sums);
            if !(rr.is_finite() && rz_new.is_finite()) {
                return Err(CgError::non_finite(it, "the residual"));
            }
            let rr = rr.max(0.0);
            if let Some(h) = &mut self.history {
                h.push(rr.sqrt() * b_norm);
            }
            if rr <= tol2 || rr == 0.0 || self.stagnated(rr.sqrt(), x) {
                axpy(alpha_t, &self.p, x);
                return Ok(Stop::Converged);
            }
            if rz_new <= 0.0 {
                // A residual already below what `T` resolves relative to `b`
                // has converged; its `M⁻¹ r` underflowed (f32 MG-PCG past
                // convergence), which is not a breakdown of the iteration.
                if rr.sqrt() < T::EPS.as_f64() {
                    axpy(alpha_t, &self.p, x);
                    return Ok(Stop::Converged);
                }
                return Err(CgError::Breakdown {
                    iteration: it,
                    reason: format!(
                        "preconditioned residual <r, M⁻¹ r> = {rz_new:e} ≤ 0 with ‖r‖ = {:e}",
                        rr.sqrt() * b_norm
                    ),
                });
            }
            let beta = T::from_f64(rz_new / rz);
            if !beta.is_finite() {
                return Err(CgError::Breakdown {
                    iteration: it,
                    reason: format!("β = {rz_new:e}/{rz:e} overflows {}", T::NAME),
                });
            }
            let m = self.z_mean(sums);
            let k = self.k.as_deref();
            let z = if self.preconditioned() {
                &self.z
            } else {
                &self.r
            };
            update_direction(alpha_t, beta, m, z, &mut self.p, x, k);
            rz = rz_new;
        }
        Ok(Stop::Cap)
    }

    /// The whole solve on the contiguous solution `x` (initial guess on entry).
    pub(super) fn solve(&mut self, b: ArrayViewD<'_, T>, x: &mut [T]) -> Result<CgInfo, CgError> {
        // Inputs: finite, and b's component along the null space.
        if b.iter().any(|v| !v.is_finite()) {
            return Err(CgError::non_finite(0, "the right-hand side b"));
        }
        let mut x_zero = true;
        for v in x.iter() {
            if !v.is_finite() {
                return Err(CgError::non_finite(0, "the initial guess x"));
            }
            x_zero &= *v == T::zero();
        }
        let k = self.k.as_deref();
        for (r, &bv) in self.r.iter_mut().zip(b.iter()) {
            *r = bv;
        }
        let b_mean = if self.projecting() {
            let m = T::from_f64(weighted_sum(&self.r, k) / self.kk);
            subtract_multiple(&mut self.r, m, k);
            if !x_zero {
                let mx = T::from_f64(weighted_sum(x, k) / self.kk);
                subtract_multiple(x, mx, k);
            }
            m
        } else {
            T::zero()
        };
        let b_norm = dot(&self.r, &self.r).sqrt();
        if !b_norm.is_finite() {
            return Err(CgError::non_finite(0, "the norm of b (overflow)"));
        }
        if b_norm == 0.0 {
            x.fill(T::zero());
            return Ok(CgInfo {
                iterations: 0,
                residual_norm: 0.0,
                relative_residual: 0.0,
                tolerance: self.params.rel_tol,
                converged: true,
                rounding_floor: None,
                restarts: 0,
                history: self.history.take().map(|mut h| {
                    h.push(0.0);
                    h
                }),
            });
        }

        // Normalise: solve A x̂ = Π b / s, x̂ = x / s.
        let s = T::from_f64(b_norm);
        if !x_zero {
            x.iter_mut().for_each(|v| *v /= s);
        }
        let tol = self.params.rel_tol.max(self.params.abs_tol / b_norm);
        let outcome = self.run(&b, b_mean, s, x, x_zero, tol, b_norm);

        // Scale back (also on error: x then holds the last iterate in original units).
        if self.projecting() {
            let k = self.k.as_deref();
            let mx = T::from_f64(weighted_sum(x, k) / self.kk);
            subtract_multiple(x, mx, k);
        }
        x.iter_mut().for_each(|v| *v *= s);
        let (true_rel, outcome, restarts) = outcome?;
        let info = CgInfo {
            iterations: self.iterations,
            residual_norm: true_rel * b_norm,
            relative_residual: true_rel,
            tolerance: tol,
            converged: outcome == Outcome::Converged,
            rounding_floor: match outcome {
                Outcome::Stalled(floor) => Some(floor),
                _ => None,
            },
            restarts,
            history: self.history.take(),
        };
        match info.failure(T::NAME) {
            Some(e) if self.params.require_convergence => Err(e),
            _ => Ok(info),
        }
    }

    /// The iterations and restarts on the normalised system; returns the true
    /// relative residual, how the solve ended, and the restarts.
    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        b: &ArrayViewD<'_, T>,
        b_mean: T,
        s: T,
        x: &mut [T],
        x_zero: bool,
        tol: f64,
        b_norm: f64,
    ) -> Result<(f64, Outcome, usize), CgError> {
        let mut sums = self.true_residual(b, b_mean, s, x, x_zero);
        let (mut rr, mut rz) = self.checked(sums)?;
        if let Some(h) = &mut self.history {
            h.push(rr.sqrt() * b_norm);
        }
        if rr.sqrt() <= tol || rr == 0.0 {
            return Ok((rr.sqrt(), Outcome::Converged, 0));
        }
        let mut restarts = 0;
        let mut last_true = f64::INFINITY;
        loop {
            self.first_direction(sums);
            let stop = self.iterate(x, rz, tol, b_norm)?;
            sums = self.true_residual(b, b_mean, s, x, false);
            (rr, rz) = self.checked(sums)?;
            let true_rel = rr.sqrt();
            if true_rel <= tol || rr == 0.0 {
                return Ok((true_rel, Outcome::Converged, restarts));
            }
            match stop {
                Stop::Cap => return Ok((true_rel, Outcome::Cap, restarts)),
                Stop::Converged => {
                    // The recurrence met the tolerance, the true residual did not:
                    // restart from it while that still gains a factor 2 and either
                    // the residual lies clearly above its rounding floor or the
                    // tolerance lies above the floor (below both, restarting only
                    // recomputes rounding errors).
                    let gaining = true_rel < 0.5 * last_true;
                    let floor = self.rounding_floor(x);
                    if restarts < self.params.max_restarts
                        && self.iterations < self.max_iters
                        && gaining
                        && (true_rel > RESTART_ABOVE_FLOOR * floor || tol >= floor)
                    {
                        restarts += 1;
                        last_true = true_rel;
                    } else {
                        return Ok((true_rel, Outcome::Stalled(floor), restarts));
                    }
                }
            }
        }
    }

    /// True once the recurrence residual `‖r̂‖` (of the normalised system) has
    /// fallen a factor `ε` below the rounding floor of the true residual: the
    /// iterate is converged to working precision, the remaining corrections
    /// `α p` no longer change it in `T`, and further iterations only shrink the
    /// recurrence towards underflow, where the curvature `<p, A p>` rounds to
    /// zero and would read as a non-positive-definite operator. Measured in
    /// `f32` on the 64² Laplacian: without this stop, fixed iteration counts of
    /// a few times what convergence needs broke down that way.
    fn stagnated(&mut self, r_norm: f64, x: &[T]) -> bool {
        let eps = T::EPS.as_f64();
        if r_norm >= eps {
            return false;
        }
        let floor = match self.floor {
            Some(f) => f,
            None => *self.floor.insert(self.rounding_floor(x)),
        };
        r_norm <= eps * floor
    }

    /// The rounding error of `b̂ − A x̂` computed in `T`, estimated as
    /// `ε·‖diag(A) ⊙ x̂‖` (for diagonally dominant operators such as Laplacians
    /// `|A| |x| ≤ 2 |diag(A)| |x|`); 0 if the operator gives no diagonal.
    fn rounding_floor(&self, x: &[T]) -> f64 {
        let weighted = |d: &mut dyn Iterator<Item = f64>| {
            d.zip(x)
                .map(|(d, &x)| (d * x.as_f64()).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let norm = if self.inv_d.is_empty() {
            match self.op.diagonal() {
                Some(d) => weighted(&mut d.iter().map(|d| d.as_f64())),
                None => 0.0,
            }
        } else {
            weighted(&mut self.inv_d.iter().map(|d| 1.0 / d.as_f64()))
        };
        T::EPS.as_f64() * norm
    }

    /// `<Π r, Π r>` (clamped at 0) and `<Π r, Π z>`, checked for NaN.
    fn checked(&self, sums: Sums) -> Result<(f64, f64), CgError> {
        let (rr, rz) = self.projected(sums);
        if !(rr.is_finite() && rz.is_finite()) {
            return Err(CgError::non_finite(self.iterations, "the residual"));
        }
        Ok((rr.max(0.0), rz))
    }
}
