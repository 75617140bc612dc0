//! The MacCormack step of one field in two sweeps over its entries.
//!
//! The step is `q̂ = A q` (with the limiter's range), `q̃ = A⁻ q̂` and
//! `q' = clamp(q̂ + (q − q̃)/2)`. Written as passes, it stores the tracing
//! velocities, `q̂`, the ranges and `q̃` in arrays of their own and runs five
//! loops. Here the first sweep computes each entry's tracing velocity, `q̂`
//! and its range, and keeps the velocity and the range beside it; the second
//! traces back from `q̂` and combines, so `q̃` is never stored. Every entry is
//! computed by the arithmetic of those passes, term for term, so the results
//! are the same bits (on any number of threads, as every entry is computed
//! alone).

use diffphys_tape::pool;

use super::lanes::{each_segment, with_workspace, SegmentVelocity, Workspace};
use super::sampling::Periodic;
use super::tracer::{for_blocks, Field, Tracer, BLOCK, PARALLEL_FROM};
use crate::buffers::{give_back, in_block_pairs, scratch};

/// What the first sweep keeps of a free entry for the second: its tracing
/// velocity and the range of the four values `q̂` interpolated from.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Traced {
    pub(super) v: [f64; 2],
    pub(super) range: [f64; 2],
}

impl Tracer<'_> {
    /// One MacCormack step of `q` over `dt` (see the module docs), clamped to
    /// the range where `limiter` is on; fixed entries copied.
    pub(super) fn maccormack(
        &self,
        field: &Field<'_>,
        q: &[f64],
        dt: f64,
        limiter: bool,
    ) -> Vec<f64> {
        let n = q.len();
        if let Some(lean) = field.sampler.periodic() {
            return self.maccormack_lanes(field, lean, q, dt, limiter);
        }
        let tables = self.tables(field.lattice);
        // every entry of `q_hat` is written, and of `traced` every free one
        let mut q_hat = scratch(n);
        let mut traced = pool::take_or(n, Traced::default());
        let split = n >= PARALLEL_FROM && rayon::current_num_threads() > 1;
        in_block_pairs(
            &mut q_hat,
            &mut traced,
            BLOCK,
            split,
            |off, q_hat, traced| {
                self.each_entry(field, off, q_hat.len(), |k, ab, p| {
                    let i = k - off;
                    if !field.free(k) {
                        q_hat[i] = q[k];
                        return;
                    }
                    let v = self.velocity_at(field.lattice, &tables, k, ab);
                    let (value, range) =
                        Self::departure(field, p, v, dt).value_and_range(q, &self.walls);
                    q_hat[i] = value;
                    traced[i] = Traced { v, range };
                });
            },
        );
        let qh: &[f64] = &q_hat;
        let back = -dt;
        let mut out = scratch(n);
        for_blocks(&mut out, |off, block| {
            self.each_entry(field, off, block.len(), |k, _, p| {
                let i = k - off;
                if !field.free(k) {
                    block[i] = q[k];
                    return;
                }
                let Traced { v, range } = traced[k];
                let q_tilde = Self::departure(field, p, v, back).value(qh, &self.walls);
                let value = qh[k] + 0.5 * (q[k] - q_tilde);
                block[i] = if limiter {
                    value.clamp(range[0], range[1])
                } else {
                    value
                };
            });
        });
        give_back(q_hat);
        give_back(traced);
        out
    }
}

impl Tracer<'_> {
    /// [`Tracer::maccormack`] on a periodic box, a segment of up to [`super::lanes::SEGMENT`] entries
    /// of a row at a time (see [`super::lanes`]): the same bits.
    fn maccormack_lanes(
        &self,
        field: &Field<'_>,
        lean: Periodic,
        q: &[f64],
        dt: f64,
        limiter: bool,
    ) -> Vec<f64> {
        let vel = SegmentVelocity::periodic(self, field.lattice);
        let n = q.len();
        let nb = field.sampler.nb;
        let [xs, ys] = &field.position;
        let all_free = field.all_free();
        let free = |k: usize| all_free || field.free(k);
        let (q_hat, traced) = self.first_sweep(field, lean, &vel, q, dt);
        let qh: &[f64] = &q_hat;
        let mut out = scratch(n);
        for_blocks(&mut out, |off, block| {
            with_workspace(|w| {
                let Workspace {
                    departures: dep,
                    v,
                    out: [q_tilde, value, _],
                    ..
                } = w;
                each_segment(nb, off, block.len(), |k0, a, b0, m| {
                    for (l, t) in traced[k0..k0 + m].iter().enumerate() {
                        // a fixed entry's `traced` is stale: trace it by zero, unused
                        let t = if free(k0 + l) { t.v } else { [0.0; 2] };
                        (v[0][l], v[1][l]) = (t[0], t[1]);
                    }
                    dep.locate(&lean, qh, xs[a], &ys[b0..b0 + m], v, -dt);
                    dep.values(q_tilde);
                    let (qh, q, q_tilde) = (&qh[k0..k0 + m], &q[k0..k0 + m], &q_tilde[..m]);
                    for l in 0..m {
                        value[l] = qh[l] + 0.5 * (q[l] - q_tilde[l]);
                    }
                    let block = &mut block[k0 - off..k0 - off + m];
                    for l in 0..m {
                        let k = k0 + l;
                        block[l] = if !free(k) {
                            q[l]
                        } else if limiter {
                            let [lo, hi] = traced[k].range;
                            value[l].clamp(lo, hi)
                        } else {
                            value[l]
                        };
                    }
                });
            });
        });
        give_back(q_hat);
        give_back(traced);
        out
    }
}

impl Tracer<'_> {
    /// The first sweep on a periodic box: `q̂ = A q` at every entry (`q` at
    /// the fixed ones), and at each free entry its tracing velocity and the
    /// limiter's range, by segments (see [`super::lanes`]).
    pub(super) fn first_sweep(
        &self,
        field: &Field<'_>,
        lean: Periodic,
        vel: &SegmentVelocity<'_>,
        q: &[f64],
        dt: f64,
    ) -> (Vec<f64>, Vec<Traced>) {
        let n = q.len();
        let nb = field.sampler.nb;
        let [xs, ys] = &field.position;
        // a box without obstacles has no fixed entry: no test per entry
        let all_free = field.all_free();
        let free = |k: usize| all_free || field.free(k);
        // every entry of `q_hat` is written, and of `traced` every free one
        let mut q_hat = scratch(n);
        let mut traced = pool::take_or(n, Traced::default());
        let split = n >= PARALLEL_FROM && rayon::current_num_threads() > 1;
        in_block_pairs(
            &mut q_hat,
            &mut traced,
            BLOCK,
            split,
            |off, q_hat, traced| {
                with_workspace(|w| {
                    let Workspace {
                        departures: dep,
                        corners,
                        v,
                        out: [value, lo, hi],
                    } = w;
                    each_segment(nb, off, q_hat.len(), |k0, a, b0, m| {
                        vel.at(a, k0, b0, m, v, corners);
                        dep.locate(&lean, q, xs[a], &ys[b0..b0 + m], v, dt);
                        dep.values(value);
                        dep.ranges(lo, hi);
                        for l in 0..m {
                            let (k, i) = (k0 + l, k0 + l - off);
                            if !free(k) {
                                q_hat[i] = q[k];
                                continue;
                            }
                            q_hat[i] = value[l];
                            traced[i] = Traced {
                                v: [v[0][l], v[1][l]],
                                range: [lo[l], hi[l]],
                            };
                        }
                    });
                });
            },
        );
        (q_hat, traced)
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

    /// The MacCormack step as separate passes over stored arrays: the
    /// reference the two sweeps must match bit for bit.
    fn by_passes(
        tr: &Tracer<'_>,
        field: &Field<'_>,
        q: &[f64],
        dt: f64,
        limiter: bool,
    ) -> Vec<f64> {
        let vel = tr.velocities(field, q.len());
        let (qh, range) = tr.first_pass(field, q, &vel, dt, limiter);
        let qt = tr.semi_lagrangian(field, &qh, &vel, -dt);
        (0..q.len())
            .map(|k| {
                if !field.free(k) {
                    return qh[k];
                }
                let v = qh[k] + 0.5 * (q[k] - qt[k]);
                if limiter {
                    v.clamp(range[k][0], range[k][1])
                } else {
                    v
                }
            })
            .collect()
    }

    /// On a periodic box (with and without an obstacle, and with rows longer
    /// than a segment), in a cavity with a moving lid and in a channel with
    /// an obstacle, on every lattice, with and without the limiter, for
    /// displacements of several cells either way.
    #[test]
    fn the_sweeps_give_the_bits_of_the_passes() {
        let (nx, ny) = (13, 9);
        let box_grid = |sides| FlowGrid {
            nx,
            ny,
            dx: 1.3 / nx as f64,
            dy: 0.7 / ny as f64,
            sides,
        };
        let open = Array2::from_elem((nx, ny), false);
        let block = Array2::from_shape_fn((nx, ny), |(i, j)| {
            (5..8).contains(&i) && (3..5).contains(&j)
        });
        // rows longer than a segment, and blocks that end inside a row
        let long = FlowGrid {
            nx: 20,
            ny: 70,
            dx: 1.3 / 20.0,
            dy: 0.7 / 70.0,
            sides: Sides::periodic(),
        };
        let cases = [
            (box_grid(Sides::periodic()), open.clone()),
            (box_grid(Sides::periodic()), block.clone()),
            (long, Array2::from_elem((20, 70), false)),
            (box_grid(Sides::cavity(0.8)), open),
            (box_grid(Sides::channel()), block),
        ];
        for (grid, solid) in &cases {
            let faces = Faces::classify(grid, solid);
            let [nfx, nfy] = [grid.shape_x(), grid.shape_y()].map(|s| s[0] * s[1]);
            let ux: Vec<f64> = (0..nfx).map(|k| 3.0 * wobble(k, 37, 101)).collect();
            let uy: Vec<f64> = (0..nfy).map(|k| 3.0 * wobble(k, 53, 89)).collect();
            let tr = tracer(grid, &ux, &uy, [0.3, -0.2, 0.8, 0.1]);
            for lattice in [Lattice::FaceX, Lattice::FaceY, Lattice::Cell] {
                let field = field_of(grid, &faces, lattice);
                let n = grid.shape(lattice).iter().product::<usize>();
                let q: Vec<f64> = (0..n).map(|k| wobble(k, 17, 71)).collect();
                for dt in [0.05, -0.4, 1.7] {
                    for limiter in [true, false] {
                        let fast = tr.maccormack(&field, &q, dt, limiter);
                        let slow = by_passes(&tr, &field, &q, dt, limiter);
                        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                        assert_eq!(bits(&fast), bits(&slow), "{lattice:?} dt {dt} {limiter}");
                    }
                }
            }
        }
    }
}
