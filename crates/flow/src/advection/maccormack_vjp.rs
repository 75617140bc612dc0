//! The vector–Jacobian product of the MacCormack step of one field.
//!
//! The step is `q̂ = A q`, `q̃ = A⁻ q̂`, `q' = clamp(q̂ + (q − q̃)/2)` (see
//! [`super`]). Where the limiter leaves an entry alone its gradient `g_k`
//! goes to `q_k` (half of it), to `q̂_k` (all of it) and to `q̃_k` (minus
//! half); where it clamps, all of it goes to the corner of `q` whose value
//! was chosen. Then `q̃ = A⁻ q̂` hands its gradient to `q̂` and `q̂ = A q` to
//! `q`, and both to the tracing velocities, which scatter it to `u`:
//!
//! ```text
//! ḡ_q̂ = g_q̂ + (A⁻)ᵀ g_q̃,   ḡ_q += ½ g + Aᵀ ḡ_q̂,   ḡ_u += I_vᵀ (∂_v A⁻ᵀ g_q̃ + ∂_v Aᵀ ḡ_q̂)
//! ```
//!
//! [`Tracer::maccormack_vjp_passes`] runs it as passes over stored arrays
//! (any boundary). On a periodic box [`Tracer::maccormack_vjp_lanes`]
//! recomputes the forward by segments and folds the passes into two sweeps
//! in entry order; every array receives the same additions in the same
//! order, so the results are the same bits.

use super::lanes::{each_segment, with_workspace, Segment, SegmentVelocity, Workspace};
use super::maccormack::Traced;
use super::sampling::Periodic;
use super::tracer::{for_blocks, Field, Grads, Tracer};
use crate::buffers::{give_back, scratch, zero_pairs, zeros};

/// The forward of a MacCormack step, recomputed for its product.
#[derive(Clone, Copy)]
struct Recomputed<'a> {
    q: &'a [f64],
    q_hat: &'a [f64],
    /// `q̃` where the limiter is on (else empty).
    q_tilde: &'a [f64],
    traced: &'a [Traced],
}

impl Recomputed<'_> {
    /// The tracing velocities of the `m` entries from `k0` into `v` (zero at
    /// fixed entries, whose `traced` is stale).
    #[inline(always)]
    fn velocities(&self, k0: usize, m: usize, free: impl Fn(usize) -> bool, v: &mut [Segment; 2]) {
        for (l, t) in self.traced[k0..k0 + m].iter().enumerate() {
            let t = if free(k0 + l) { t.v } else { [0.0; 2] };
            (v[0][l], v[1][l]) = (t[0], t[1]);
        }
    }
}

impl Tracer<'_> {
    /// Adds the product of the MacCormack step with `g` to `grads` and to
    /// `g_v` (the tracing velocities' gradient, `vel` the velocities), as
    /// separate passes: the reference of [`Tracer::maccormack_vjp_lanes`].
    #[allow(clippy::too_many_arguments)]
    pub(super) fn maccormack_vjp_passes(
        &self,
        field: &Field<'_>,
        q: &[f64],
        vel: &[[f64; 2]],
        dt: f64,
        limiter: bool,
        g: &[f64],
        grads: &mut Grads,
        g_v: &mut [[f64; 2]],
    ) {
        let n = q.len();
        let (qh, range) = self.first_pass(field, q, vel, dt, limiter);
        let qt = self.semi_lagrangian(field, &qh, vel, -dt);
        let mut g_hat = zeros(n);
        let mut g_tilde = zeros(n);
        self.each_entry(field, 0, n, |k, _, p| {
            let gk = g[k];
            if !field.free(k) {
                grads.q[k] += gk;
                return;
            }
            if limiter {
                let v = qh[k] + 0.5 * (q[k] - qt[k]);
                let [lo, hi] = range[k];
                if v < lo || v > hi {
                    self.clamped_vjp(field, p, vel[k], dt, q, v, gk, grads);
                    return;
                }
            }
            g_hat[k] += gk;
            grads.q[k] += 0.5 * gk;
            g_tilde[k] = -0.5 * gk;
        });
        // q̃ = A⁻ q̂: its field gradient lands on q̂.
        let mut inner = Grads::zeros(n, 0, 0);
        self.semi_lagrangian_vjp(field, &qh, vel, -dt, &g_tilde, &mut inner, g_v);
        for (a, b) in g_hat.iter_mut().zip(&inner.q) {
            *a += b;
        }
        inner.q.iter_mut().for_each(|v| *v = 0.0);
        // q̂ = A q.
        self.semi_lagrangian_vjp(field, q, vel, dt, &g_hat, &mut inner, g_v);
        grads.add(&inner);
        for v in [qh, qt, g_hat, g_tilde, inner.q, inner.ux, inner.uy] {
            give_back(v);
        }
        give_back(range);
    }

    /// A clamped entry at `p` traced by `v` whose unclamped value was
    /// `value`: its gradient `gk` goes to the corner of `q` that was chosen.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn clamped_vjp(
        &self,
        field: &Field<'_>,
        p: [f64; 2],
        v: [f64; 2],
        dt: f64,
        q: &[f64],
        value: f64,
        gk: f64,
        grads: &mut Grads,
    ) {
        let dep = Self::departure(field, p, v, dt);
        let (lo, hi) = dep.extremes(q, &self.walls);
        let (a, b, _) = if value < lo.2 { lo } else { hi };
        dep.scatter_corner(a, b, gk, &mut grads.q, &mut grads.walls);
    }

    /// [`Tracer::maccormack_vjp_passes`] and [`Tracer::velocities_vjp`] on a
    /// periodic box (`lean`), added to `grads`. The forward is recomputed by
    /// the segment sweeps of [`Tracer::maccormack`] (`q̂`, the velocities and
    /// ranges, and `q̃` where the limiter needs it); then one sweep applies
    /// the combination's product and `(A⁻)ᵀ`, and a second `Aᵀ` and the
    /// velocities' product, entry by entry. No array of the passes' is
    /// written in another order, so the same bits.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn maccormack_vjp_lanes(
        &self,
        field: &Field<'_>,
        lean: Periodic,
        q: &[f64],
        dt: f64,
        limiter: bool,
        g: &[f64],
        grads: &mut Grads,
    ) {
        let n = q.len();
        let vel = SegmentVelocity::periodic(self, field.lattice);
        let (q_hat, traced) = self.first_sweep(field, lean, &vel, q, dt);
        let q_tilde = if limiter {
            self.back_sweep(field, lean, &q_hat, &traced, dt)
        } else {
            Vec::new()
        };
        let forward = Recomputed {
            q,
            q_hat: &q_hat,
            q_tilde: &q_tilde,
            traced: &traced,
        };
        let mut g_hat = zeros(n);
        let mut g_v = zero_pairs(n);
        // (A⁻)ᵀ g_q̃, the gradient of q̂ through q̃
        let mut through_tilde = zeros(n);
        self.tilde_product(
            field,
            lean,
            &forward,
            dt,
            limiter,
            g,
            grads,
            [&mut g_hat, &mut through_tilde],
            &mut g_v,
        );
        // Aᵀ ḡ_q̂ into a zeroed array (added to `grads.q` after, as the
        // passes do), and each entry's velocity gradient, now complete
        let mut through_hat = zeros(n);
        self.hat_product(
            field,
            lean,
            &forward,
            dt,
            [&g_hat, &through_tilde],
            &mut through_hat,
            &mut g_v,
            grads,
        );
        for (a, b) in grads.q.iter_mut().zip(&through_hat) {
            *a += b;
        }
        for v in [q_hat, q_tilde, g_hat, through_tilde, through_hat] {
            give_back(v);
        }
        give_back(traced);
        give_back(g_v);
    }

    /// The first sweep of [`Tracer::maccormack_vjp_lanes`], by segments in
    /// entry order: the combination's product with `g` (to `grads.q`, to
    /// `g_hat` and, for a clamped entry, to its chosen corner), and that of
    /// `q̃ = A⁻ q̂` with `−g/2` (to `through_tilde` and `g_v`).
    #[allow(clippy::too_many_arguments)]
    fn tilde_product(
        &self,
        field: &Field<'_>,
        lean: Periodic,
        fw: &Recomputed<'_>,
        dt: f64,
        limiter: bool,
        g: &[f64],
        grads: &mut Grads,
        [g_hat, through_tilde]: [&mut [f64]; 2],
        g_v: &mut [[f64; 2]],
    ) {
        let [xs, ys] = &field.position;
        let all_free = field.all_free();
        let free = |k: usize| all_free || field.free(k);
        let f = self.slope_factors(-dt);
        let Recomputed {
            q,
            q_hat,
            q_tilde,
            traced,
        } = *fw;
        with_workspace(|w| {
            let Workspace {
                departures: dep,
                v,
                out: [slx, sly, _],
                ..
            } = w;
            each_segment(field.sampler.nb, 0, q.len(), |k0, a, b0, m| {
                fw.velocities(k0, m, free, v);
                dep.locate(&lean, q_hat, xs[a], &ys[b0..b0 + m], v, -dt);
                dep.slopes(slx, sly);
                for l in 0..m {
                    let (k, p) = (k0 + l, [xs[a], ys[b0 + l]]);
                    let gk = g[k];
                    if !free(k) {
                        grads.q[k] += gk;
                        continue;
                    }
                    if limiter {
                        let value = q_hat[k] + 0.5 * (q[k] - q_tilde[k]);
                        let [lo, hi] = traced[k].range;
                        if value < lo || value > hi {
                            self.clamped_vjp(field, p, traced[k].v, dt, q, value, gk, grads);
                            continue;
                        }
                    }
                    g_hat[k] += gk;
                    grads.q[k] += 0.5 * gk;
                    let g_tilde = -0.5 * gk;
                    if g_tilde != 0.0 {
                        let gv = if dep.indexed() {
                            dep.scatter(l, g_tilde, through_tilde);
                            [f[0] * g_tilde * slx[l], f[1] * g_tilde * sly[l]]
                        } else {
                            let v = traced[k].v;
                            Self::periodic_entry_vjp(
                                lean,
                                p,
                                v,
                                -dt,
                                f,
                                q_hat,
                                g_tilde,
                                through_tilde,
                            )
                        };
                        g_v[k][0] += gv[0];
                        g_v[k][1] += gv[1];
                    }
                }
            });
        });
    }

    /// The second sweep of [`Tracer::maccormack_vjp_lanes`], by segments in
    /// entry order: `q̂ = A q`'s product with `ḡ_q̂ = g_hat + through_tilde`
    /// (to `through_hat` and `g_v`), then each entry's velocity gradient
    /// scattered to `u` ([`Tracer::velocity_vjp_at`]).
    #[allow(clippy::too_many_arguments)]
    fn hat_product(
        &self,
        field: &Field<'_>,
        lean: Periodic,
        fw: &Recomputed<'_>,
        dt: f64,
        [g_hat, through_tilde]: [&[f64]; 2],
        through_hat: &mut [f64],
        g_v: &mut [[f64; 2]],
        grads: &mut Grads,
    ) {
        let [xs, ys] = &field.position;
        let all_free = field.all_free();
        let free = |k: usize| all_free || field.free(k);
        let f = self.slope_factors(dt);
        let tables = self.tables(field.lattice);
        let q = fw.q;
        with_workspace(|w| {
            let Workspace {
                departures: dep,
                v,
                out: [slx, sly, _],
                ..
            } = w;
            each_segment(field.sampler.nb, 0, q.len(), |k0, a, b0, m| {
                fw.velocities(k0, m, free, v);
                dep.locate(&lean, q, xs[a], &ys[b0..b0 + m], v, dt);
                dep.slopes(slx, sly);
                for l in 0..m {
                    let k = k0 + l;
                    let gh = g_hat[k] + through_tilde[k];
                    if !free(k) {
                        through_hat[k] += gh;
                        continue;
                    }
                    if gh != 0.0 {
                        let gv = if dep.indexed() {
                            dep.scatter(l, gh, through_hat);
                            [f[0] * gh * slx[l], f[1] * gh * sly[l]]
                        } else {
                            let (p, v) = ([xs[a], ys[b0 + l]], fw.traced[k].v);
                            Self::periodic_entry_vjp(lean, p, v, dt, f, q, gh, through_hat)
                        };
                        g_v[k][0] += gv[0];
                        g_v[k][1] += gv[1];
                    }
                    self.velocity_vjp_at(field.lattice, &tables, k, [a, b0 + l], g_v[k], grads);
                }
            });
        });
    }

    /// `q̃ = A⁻ q̂` at every free entry of a periodic box, traced back by the
    /// velocities of the first sweep, by segments (a fixed entry's value is
    /// unspecified).
    fn back_sweep(
        &self,
        field: &Field<'_>,
        lean: Periodic,
        q_hat: &[f64],
        traced: &[Traced],
        dt: f64,
    ) -> Vec<f64> {
        let nb = field.sampler.nb;
        let [xs, ys] = &field.position;
        let all_free = field.all_free();
        let free = |k: usize| all_free || field.free(k);
        // every entry is written
        let mut out = scratch(q_hat.len());
        for_blocks(&mut out, |off, block| {
            with_workspace(|w| {
                let Workspace {
                    departures: dep,
                    v,
                    out: [q_tilde, ..],
                    ..
                } = w;
                each_segment(nb, off, block.len(), |k0, a, b0, m| {
                    for (l, t) in traced[k0..k0 + m].iter().enumerate() {
                        // a fixed entry's `traced` is stale: trace it by zero, unused
                        let t = if free(k0 + l) { t.v } else { [0.0; 2] };
                        (v[0][l], v[1][l]) = (t[0], t[1]);
                    }
                    dep.locate(&lean, q_hat, xs[a], &ys[b0..b0 + m], v, -dt);
                    dep.values(q_tilde);
                    block[k0 - off..k0 - off + m].copy_from_slice(&q_tilde[..m]);
                });
            });
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::super::tracer::{field_of, tracer};
    use super::*;
    use crate::boundaries::Faces;
    use crate::grid::{FlowGrid, Lattice};
    use crate::sides::Sides;
    use ndarray::Array2;

    /// A value in [-1, 1) from an index, deterministic.
    fn wobble(k: usize, a: usize, b: usize) -> f64 {
        ((k * a % b) as f64 / b as f64) * 2.0 - 1.0
    }

    /// The product by the passes, with the velocities' product after.
    fn by_passes(
        tr: &Tracer<'_>,
        field: &Field<'_>,
        q: &[f64],
        dt: f64,
        limiter: bool,
        g: &[f64],
        grads: &mut Grads,
    ) {
        let vel = tr.velocities(field, q.len());
        let mut g_v = vec![[0.0; 2]; q.len()];
        tr.maccormack_vjp_passes(field, q, &vel, dt, limiter, g, grads, &mut g_v);
        tr.velocities_vjp(field, &g_v, grads);
    }

    /// On a periodic box with and without an obstacle, and with rows longer
    /// than a segment, on every lattice, with and without the limiter, for
    /// displacements of several cells either way, with gradients that are
    /// zero at some entries: the bits of the passes, in every gradient.
    #[test]
    fn the_fused_product_gives_the_bits_of_the_passes() {
        let grid = |nx: usize, ny: usize| FlowGrid {
            nx,
            ny,
            dx: 1.3 / nx as f64,
            dy: 0.7 / ny as f64,
            sides: Sides::periodic(),
        };
        let block =
            Array2::from_shape_fn((13, 9), |(i, j)| (5..8).contains(&i) && (3..5).contains(&j));
        let cases = [
            (grid(13, 9), Array2::from_elem((13, 9), false)),
            (grid(13, 9), block),
            (grid(20, 70), Array2::from_elem((20, 70), false)),
        ];
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let mut clamped = 0;
        for (grid, solid) in &cases {
            let faces = Faces::classify(grid, solid);
            let [nfx, nfy] = [grid.shape_x(), grid.shape_y()].map(|s| s[0] * s[1]);
            let ux: Vec<f64> = (0..nfx).map(|k| 3.0 * wobble(k, 37, 101)).collect();
            let uy: Vec<f64> = (0..nfy).map(|k| 3.0 * wobble(k, 53, 89)).collect();
            let tr = tracer(grid, &ux, &uy, [0.0; 4]);
            for lattice in [Lattice::FaceX, Lattice::FaceY, Lattice::Cell] {
                let field = field_of(grid, &faces, lattice);
                let lean = field.sampler.periodic().expect("a periodic box");
                let n = grid.shape(lattice).iter().product::<usize>();
                let q: Vec<f64> = (0..n).map(|k| wobble(k, 17, 71)).collect();
                let g: Vec<f64> = (0..n)
                    .map(|k| if k % 7 == 3 { 0.0 } else { wobble(k, 29, 83) })
                    .collect();
                for dt in [0.05, -0.4, 1.7] {
                    for limiter in [true, false] {
                        let mut fast = Grads::zeros(n, nfx, nfy);
                        tr.maccormack_vjp_lanes(&field, lean, &q, dt, limiter, &g, &mut fast);
                        let mut slow = Grads::zeros(n, nfx, nfy);
                        by_passes(&tr, &field, &q, dt, limiter, &g, &mut slow);
                        let what = format!("{lattice:?} dt {dt} limiter {limiter}");
                        assert_eq!(bits(&fast.q), bits(&slow.q), "q: {what}");
                        assert_eq!(bits(&fast.ux), bits(&slow.ux), "ux: {what}");
                        assert_eq!(bits(&fast.uy), bits(&slow.uy), "uy: {what}");
                        assert_eq!(bits(&fast.walls), bits(&slow.walls), "walls: {what}");
                        assert!(slow.ux.iter().any(|&v| v != 0.0), "{what}");
                        if limiter {
                            let step = tr.maccormack(&field, &q, dt, false);
                            let lim = tr.maccormack(&field, &q, dt, true);
                            clamped += step.iter().zip(&lim).filter(|(a, b)| a != b).count();
                        }
                    }
                }
            }
        }
        // the limiter's branch of the product is exercised
        assert!(clamped > 0);
    }
}
