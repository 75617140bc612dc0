//! The semi-Lagrangian and MacCormack steps of one field and their
//! vector–Jacobian products, traced by a staggered velocity.

use super::sampling::{
    bilinear, bilinear_scatter, bilinear_slopes, corner_values, LatticeStencils, Periodic, Sampler,
    Stencil,
};
use super::Advection;
use crate::boundaries::{FaceKind, Faces};
use crate::buffers::{give_back, in_block_pairs, in_blocks, scratch, zero_pairs, zeros};
use crate::grid::{FlowGrid, Lattice};
use diffphys_tape::pool;

/// The velocity field a step traces with.
pub(super) struct Tracer<'a> {
    pub(super) grid: &'a FlowGrid,
    pub(super) ux: &'a [f64],
    pub(super) uy: &'a [f64],
    pub(super) walls: [f64; 4],
    pub(super) sx: Sampler,
    pub(super) sy: Sampler,
}

/// One field being advected: its lattice, sampler and free entries.
pub(super) struct Field<'a> {
    pub(super) lattice: Lattice,
    pub(super) sampler: Sampler,
    pub(super) kinds: &'a [FaceKind],
    /// The coordinates of its entries along x (by row `a`) and y (by `b`):
    /// entry `(a, b)` is at `(position[0][a], position[1][b])`.
    pub(super) position: [Vec<f64>; 2],
}

impl Field<'_> {
    pub(super) fn free(&self, k: usize) -> bool {
        self.kinds.get(k).is_none_or(|kind| *kind == FaceKind::Free)
    }

    /// Whether every entry is free (no wall, inflow or obstacle face).
    pub(super) fn all_free(&self) -> bool {
        self.kinds.iter().all(|kind| *kind == FaceKind::Free)
    }
}

/// Entries per block of the loops that compute each entry on its own; the
/// blocks run on all cores from [`PARALLEL_FROM`] entries. Every entry is
/// computed by the same arithmetic wherever it runs, so the results do not
/// depend on the number of threads.
pub(super) const BLOCK: usize = 1024;

/// The number of entries from which the per-entry loops use all cores (an
/// entry costs a few bilinear interpolations, about a hundred times a CG
/// kernel's element).
pub(crate) const PARALLEL_FROM: usize = 8192;

/// Runs `f(offset, block)` on the [`BLOCK`]-sized blocks of `out`.
pub(super) fn for_blocks<V: Send>(out: &mut [V], f: impl Fn(usize, &mut [V]) + Sync + Send) {
    let split = out.len() >= PARALLEL_FROM && rayon::current_num_threads() > 1;
    in_blocks(out, BLOCK, split, f);
}

impl Tracer<'_> {
    /// Runs `f(k, [a, b], x_k)` on the entries `off..off + len` of `field` in
    /// order, `(a, b)` the entry's index and `x_k` its position (as
    /// [`FlowGrid::position`], without a division per entry).
    pub(super) fn each_entry(
        &self,
        field: &Field<'_>,
        off: usize,
        len: usize,
        mut f: impl FnMut(usize, [usize; 2], [f64; 2]),
    ) {
        let nb = field.sampler.nb;
        let [xs, ys] = &field.position;
        let end = off + len;
        let mut k = off;
        // row by row: the row's coordinate once, the row's end without a test per entry
        while k < end {
            let (a, first) = (k / nb, k % nb);
            let last = nb.min(first + end - k);
            let x = xs[a];
            for (b, &y) in ys.iter().enumerate().take(last).skip(first) {
                f(k, [a, b], [x, y]);
                k += 1;
            }
        }
    }

    /// `v(x_k) = (I_ux(x_k), I_uy(x_k))` at every free entry of `field`
    /// (zero at fixed entries, which are not traced). Computed once per step
    /// and shared by its passes; the stencils come from the per-axis tables
    /// of [`Sampler::on_lattice`]. On a face lattice the component that lives
    /// there is read, not interpolated: `I_ux` at an x-face is `u_x` there
    /// (the bilinear weights of a lattice point are 1 and 0 up to rounding).
    pub(super) fn velocities(&self, field: &Field<'_>, len: usize) -> Vec<[f64; 2]> {
        let tables = self.tables(field.lattice);
        let mut v = zero_pairs(len);
        for_blocks(&mut v, |off, out| {
            self.each_entry(field, off, out.len(), |k, ab, _| {
                if field.free(k) {
                    out[k - off] = self.velocity_at(field.lattice, &tables, k, ab);
                }
            });
        });
        v
    }

    /// The velocity samplers' stencils at the entries of `lattice`.
    pub(super) fn tables(&self, lattice: Lattice) -> [LatticeStencils; 2] {
        [
            self.sx.on_lattice(self.grid, lattice),
            self.sy.on_lattice(self.grid, lattice),
        ]
    }

    /// [`Tracer::velocities`] at the free entry `k`, `(a, b)`, of a field on
    /// `own`, from its [`Tracer::tables`].
    #[inline(always)]
    pub(super) fn velocity_at(
        &self,
        own: Lattice,
        [tx, ty]: &[LatticeStencils; 2],
        k: usize,
        ab: [usize; 2],
    ) -> [f64; 2] {
        match own {
            Lattice::FaceX => [self.ux[k], ty.value_at(ab, self.uy, &self.walls)],
            Lattice::FaceY => [tx.value_at(ab, self.ux, &self.walls), self.uy[k]],
            Lattice::Cell => [
                tx.value_at(ab, self.ux, &self.walls),
                ty.value_at(ab, self.uy, &self.walls),
            ],
        }
    }

    /// Adds `I_vᵀ g_v` (the adjoint of [`Tracer::velocities`]) to the
    /// gradients of `u_x`, `u_y` and the walls.
    pub(super) fn velocities_vjp(&self, field: &Field<'_>, g_v: &[[f64; 2]], grads: &mut Grads) {
        let tables = self.tables(field.lattice);
        self.each_entry(field, 0, g_v.len(), |k, ab, _| {
            self.velocity_vjp_at(field.lattice, &tables, k, ab, g_v[k], grads);
        });
    }

    /// The adjoint of [`Tracer::velocity_at`] with `g` (the gradient of the
    /// entry's velocity), added to `grads`.
    #[inline(always)]
    pub(super) fn velocity_vjp_at(
        &self,
        own: Lattice,
        [tx, ty]: &[LatticeStencils; 2],
        k: usize,
        ab: [usize; 2],
        g: [f64; 2],
        grads: &mut Grads,
    ) {
        if g[0] != 0.0 {
            if own == Lattice::FaceX {
                grads.ux[k] += g[0];
            } else {
                tx.scatter_at(ab, g[0], &mut grads.ux, &mut grads.walls);
            }
        }
        if g[1] != 0.0 {
            if own == Lattice::FaceY {
                grads.uy[k] += g[1];
            } else {
                ty.scatter_at(ab, g[1], &mut grads.uy, &mut grads.walls);
            }
        }
    }

    /// The vector–Jacobian product of [`Tracer::periodic_step`] with `g`,
    /// added to `grads`: [`Tracer::semi_lagrangian_vjp`] and
    /// [`Tracer::velocities_vjp`] in one pass, without the velocities' and
    /// their gradient's arrays. The velocity gradients are added in entry
    /// order as there, and the field's go to another array: the same bits.
    pub(super) fn periodic_step_vjp(
        &self,
        field: &Field<'_>,
        lean: Periodic,
        q: &[f64],
        dt: f64,
        g: &[f64],
        grads: &mut Grads,
    ) {
        let tables = self.tables(field.lattice);
        let f = self.slope_factors(dt);
        self.each_gradient(field, g, grads, |grads, k, ab, p, gk| {
            let v = self.velocity_at(field.lattice, &tables, k, ab);
            let g_v = Self::periodic_entry_vjp(lean, p, v, dt, f, q, gk, &mut grads.q);
            self.velocity_vjp_at(field.lattice, &tables, k, ab, g_v, grads);
        });
    }

    /// Runs `f(grads, k, (a, b), x_k, g_k)` at the free entries of `field`
    /// whose gradient `g_k` is not zero, in order; a fixed entry's gradient
    /// goes to `grads.q` unchanged (the step copies it).
    pub(super) fn each_gradient(
        &self,
        field: &Field<'_>,
        g: &[f64],
        grads: &mut Grads,
        mut f: impl FnMut(&mut Grads, usize, [usize; 2], [f64; 2], f64),
    ) {
        self.each_entry(field, 0, g.len(), |k, ab, p| {
            let gk = g[k];
            if !field.free(k) {
                grads.q[k] += gk;
            } else if gk != 0.0 {
                f(grads, k, ab, p, gk);
            }
        });
    }

    /// The stencil at the departure point `p − dt v` of the entry at `p`.
    #[inline(always)]
    pub(super) fn departure(field: &Field<'_>, p: [f64; 2], v: [f64; 2], dt: f64) -> Stencil {
        field.sampler.locate([p[0] - dt * v[0], p[1] - dt * v[1]])
    }

    /// `at(stencil)` of the departure stencil over `dt` at every free entry of
    /// `field` (traced by `vel`), `q[k]` at the fixed entries, into a buffer
    /// from the pool.
    pub(super) fn at_departures(
        &self,
        field: &Field<'_>,
        q: &[f64],
        vel: &[[f64; 2]],
        dt: f64,
        at: impl Fn(Stencil) -> f64 + Sync + Send,
    ) -> Vec<f64> {
        // every entry is written
        let mut out = scratch(vel.len());
        for_blocks(&mut out, |off, block| {
            self.each_entry(field, off, block.len(), |k, _, p| {
                block[k - off] = if field.free(k) {
                    at(Self::departure(field, p, vel[k], dt))
                } else {
                    q[k]
                };
            });
        });
        out
    }

    /// `A q`: one semi-Lagrangian step of `q` with the tracing velocities
    /// `vel` (fixed entries copied).
    pub(super) fn semi_lagrangian(
        &self,
        field: &Field<'_>,
        q: &[f64],
        vel: &[[f64; 2]],
        dt: f64,
    ) -> Vec<f64> {
        let Some(lean) = field.sampler.periodic() else {
            return self.at_departures(field, q, vel, dt, |s| s.value(q, &self.walls));
        };
        // every entry is written
        let mut out = scratch(vel.len());
        for_blocks(&mut out, |off, block| {
            self.each_entry(field, off, block.len(), |k, _, p| {
                block[k - off] = if field.free(k) {
                    let v = vel[k];
                    let (c, wx, wy) = lean.locate([p[0] - dt * v[0], p[1] - dt * v[1]]);
                    bilinear(corner_values(q, c), wx, wy)
                } else {
                    q[k]
                };
            });
        });
        out
    }

    /// `A q` and, at each free entry, the smallest and largest of the four
    /// values it interpolated from (the limiter's range).
    pub(super) fn semi_lagrangian_ranged(
        &self,
        field: &Field<'_>,
        q: &[f64],
        vel: &[[f64; 2]],
        dt: f64,
    ) -> (Vec<f64>, Vec<[f64; 2]>) {
        let n = vel.len();
        // every entry of both is written
        let mut values = scratch(n);
        let mut ranges = pool::take_or(n, [0.0; 2]);
        let split = n >= PARALLEL_FROM && rayon::current_num_threads() > 1;
        in_block_pairs(
            &mut values,
            &mut ranges,
            BLOCK,
            split,
            |off, values, ranges| {
                self.each_entry(field, off, values.len(), |k, _, p| {
                    let i = k - off;
                    (values[i], ranges[i]) = if field.free(k) {
                        Self::departure(field, p, vel[k], dt).value_and_range(q, &self.walls)
                    } else {
                        (q[k], [q[k]; 2])
                    };
                });
            },
        );
        (values, ranges)
    }

    /// `q̂ = A q`, with the limiter's range where `limiter` is on (else empty).
    pub(super) fn first_pass(
        &self,
        field: &Field<'_>,
        q: &[f64],
        vel: &[[f64; 2]],
        dt: f64,
        limiter: bool,
    ) -> (Vec<f64>, Vec<[f64; 2]>) {
        if limiter {
            self.semi_lagrangian_ranged(field, q, vel, dt)
        } else {
            (self.semi_lagrangian(field, q, vel, dt), Vec::new())
        }
    }

    /// Adds the vector–Jacobian product of `A q` with `g` to the gradients
    /// of `q` and the walls, and to `g_v`, the gradient of the tracing
    /// velocities (scattered to `u` once, by [`Tracer::velocities_vjp`]).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn semi_lagrangian_vjp(
        &self,
        field: &Field<'_>,
        q: &[f64],
        vel: &[[f64; 2]],
        dt: f64,
        g: &[f64],
        grads: &mut Grads,
        g_v: &mut [[f64; 2]],
    ) {
        let f = self.slope_factors(dt);
        let lean = field.sampler.periodic();
        self.each_gradient(field, g, grads, |grads, k, _, p, gk| {
            if let Some(lean) = lean {
                let gv = Self::periodic_entry_vjp(lean, p, vel[k], dt, f, q, gk, &mut grads.q);
                g_v[k][0] += gv[0];
                g_v[k][1] += gv[1];
                return;
            }
            let dep = Self::departure(field, p, vel[k], dt);
            dep.scatter(gk, &mut grads.q, &mut grads.walls);
            let (slx, sly) = dep.slopes(q, &self.walls);
            g_v[k][0] += f[0] * gk * slx;
            g_v[k][1] += f[1] * gk * sly;
        });
    }

    /// The adjoint at one free entry at `p` traced by `v` on a periodic box
    /// (`f` the [`Tracer::slope_factors`]): `gk` scattered onto `grad_q`, the
    /// gradient of the tracing velocity returned. [`Stencil::scatter`] and
    /// [`Stencil::slopes`], term for term.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn periodic_entry_vjp(
        lean: Periodic,
        p: [f64; 2],
        v: [f64; 2],
        dt: f64,
        f: [f64; 2],
        q: &[f64],
        gk: f64,
        grad_q: &mut [f64],
    ) -> [f64; 2] {
        let (c, wx, wy) = lean.locate([p[0] - dt * v[0], p[1] - dt * v[1]]);
        bilinear_scatter(c, wx, wy, gk, grad_q);
        let (slx, sly) = bilinear_slopes(corner_values(q, c), wx, wy);
        [f[0] * gk * slx, f[1] * gk * sly]
    }

    /// `−dt/h` along x and y: the departure point's derivative in lattice
    /// units by the tracing velocity, which scales the interpolant's slopes.
    pub(super) fn slope_factors(&self, dt: f64) -> [f64; 2] {
        [-dt / self.grid.dx, -dt / self.grid.dy]
    }

    /// One step of `scheme`.
    pub(super) fn step(
        &self,
        field: &Field<'_>,
        q: &[f64],
        dt: f64,
        scheme: Advection,
    ) -> Vec<f64> {
        if let (Advection::SemiLagrangian, Some(lean)) = (scheme, field.sampler.periodic()) {
            return self.periodic_step(field, lean, q, dt);
        }
        if let Advection::MacCormack { limiter } = scheme {
            return self.maccormack(field, q, dt, limiter);
        }
        let vel = self.velocities(field, q.len());
        let out = self.semi_lagrangian(field, q, &vel, dt);
        give_back(vel);
        out
    }

    /// Adds the vector–Jacobian product of [`Tracer::step`] to `grads`.
    pub(super) fn step_vjp(
        &self,
        field: &Field<'_>,
        q: &[f64],
        dt: f64,
        scheme: Advection,
        g: &[f64],
        grads: &mut Grads,
    ) {
        match (scheme, field.sampler.periodic()) {
            (Advection::SemiLagrangian, Some(lean)) => {
                return self.periodic_step_vjp(field, lean, q, dt, g, grads);
            }
            (Advection::MacCormack { limiter }, Some(lean)) => {
                return self.maccormack_vjp_lanes(field, lean, q, dt, limiter, g, grads);
            }
            _ => {}
        }
        let n = q.len();
        let vel = self.velocities(field, n);
        let mut g_v = zero_pairs(n);
        let Advection::MacCormack { limiter } = scheme else {
            self.semi_lagrangian_vjp(field, q, &vel, dt, g, grads, &mut g_v);
            self.velocities_vjp(field, &g_v, grads);
            give_back(vel);
            give_back(g_v);
            return;
        };
        self.maccormack_vjp_passes(field, q, &vel, dt, limiter, g, grads, &mut g_v);
        self.velocities_vjp(field, &g_v, grads);
        give_back(vel);
        give_back(g_v);
    }
}

/// Gradients of one advected field and of the velocity that carries it.
pub(super) struct Grads {
    pub(super) q: Vec<f64>,
    pub(super) ux: Vec<f64>,
    pub(super) uy: Vec<f64>,
    pub(super) walls: [f64; 4],
}

impl Grads {
    pub(super) fn zeros(nq: usize, nx: usize, ny: usize) -> Self {
        Grads {
            q: zeros(nq),
            ux: zeros(nx),
            uy: zeros(ny),
            walls: [0.0; 4],
        }
    }

    /// Adds `o` (whose velocity gradients may be empty: none).
    pub(super) fn add(&mut self, o: &Grads) {
        for (a, b) in [
            (&mut self.q, &o.q),
            (&mut self.ux, &o.ux),
            (&mut self.uy, &o.uy),
        ] {
            a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        }
        for s in 0..4 {
            self.walls[s] += o.walls[s];
        }
    }
}

pub(super) fn field_of<'a>(grid: &FlowGrid, faces: &'a Faces, lattice: Lattice) -> Field<'a> {
    let [na, nb] = grid.shape(lattice);
    let (oa, ob) = lattice.offsets();
    Field {
        lattice,
        sampler: Sampler::new(grid, lattice),
        kinds: faces.of(lattice),
        position: [
            (0..na).map(|a| (a as f64 + oa) * grid.dx).collect(),
            (0..nb).map(|b| (b as f64 + ob) * grid.dy).collect(),
        ],
    }
}

pub(super) fn tracer<'a>(
    grid: &'a FlowGrid,
    ux: &'a [f64],
    uy: &'a [f64],
    walls: [f64; 4],
) -> Tracer<'a> {
    Tracer {
        grid,
        ux,
        uy,
        walls,
        sx: Sampler::new(grid, Lattice::FaceX),
        sy: Sampler::new(grid, Lattice::FaceY),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::advection::sampling::*;
    use crate::sides::Sides;
    use ndarray::Array2;

    /// A grid of `nx × ny` cells over `size` with `sides`, no obstacle.
    fn grid_and_faces(nx: usize, ny: usize, size: [f64; 2], sides: Sides) -> (FlowGrid, Faces) {
        let grid = FlowGrid {
            nx,
            ny,
            dx: size[0] / nx as f64,
            dy: size[1] / ny as f64,
            sides,
        };
        let faces = Faces::classify(&grid, &Array2::from_elem((nx, ny), false));
        (grid, faces)
    }

    /// A value in [-1, 1) from an index, deterministic.
    fn wobble(k: usize, a: usize, b: usize) -> f64 {
        ((k * a % b) as f64 / b as f64) * 2.0 - 1.0
    }

    /// The lattice tables' direct scatter is the stencil's, bit for bit, at
    /// every entry of every lattice, beside walls and a moving lid too.
    #[test]
    fn table_scatter_matches_the_stencils() {
        let lid = grid_and_faces(7, 6, [1.0, 1.0], Sides::cavity(0.8)).0;
        let periodic = grid_and_faces(6, 5, [1.0, 1.0], Sides::periodic()).0;
        for grid in [lid, periodic] {
            let g = &grid;
            for lattice in [Lattice::FaceX, Lattice::FaceY, Lattice::Cell] {
                let [na, nb] = g.shape(lattice);
                for sampled in [Lattice::FaceX, Lattice::FaceY] {
                    let sampler = Sampler::new(g, sampled);
                    let table = sampler.on_lattice(g, lattice);
                    let len = g.shape(sampled).iter().product::<usize>();
                    let (mut fast, mut slow) = (vec![0.0; len], vec![0.0; len]);
                    let (mut fast_w, mut slow_w) = ([0.0; 4], [0.0; 4]);
                    for a in 0..na {
                        for b in 0..nb {
                            let c = wobble(a * nb + b, 31, 97);
                            table.scatter_at([a, b], c, &mut fast, &mut fast_w);
                            table.at([a, b]).scatter(c, &mut slow, &mut slow_w);
                        }
                    }
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&fast), bits(&slow));
                    assert_eq!(bits(&fast_w), bits(&slow_w));
                }
            }
        }
    }

    /// The periodic box's lean path gives the bits of the stencils it
    /// replaces: the semi-Lagrangian values and its vector–Jacobian product,
    /// for displacements of several cells either way (wraps included).
    #[test]
    fn periodic_path_matches_the_stencils() {
        // rows shorter and longer than a segment of the lane loops
        for (nx, ny) in [(13, 9), (20, 70)] {
            periodic_path_matches_the_stencils_on(nx, ny);
        }
    }

    fn periodic_path_matches_the_stencils_on(nx: usize, ny: usize) {
        let (grid, faces) = grid_and_faces(nx, ny, [1.3, 0.7], Sides::periodic());
        let g = &grid;
        let (nx, ny) = (
            g.shape_x().iter().product::<usize>(),
            g.shape_y().iter().product::<usize>(),
        );
        let ux: Vec<f64> = (0..nx).map(|k| 3.0 * wobble(k, 37, 101)).collect();
        let uy: Vec<f64> = (0..ny).map(|k| 3.0 * wobble(k, 53, 89)).collect();
        let walls = [0.0; 4];
        let tr = tracer(g, &ux, &uy, walls);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for lattice in [Lattice::FaceX, Lattice::FaceY, Lattice::Cell] {
            let field = field_of(g, &faces, lattice);
            assert!(field.sampler.periodic().is_some());
            let n = g.shape(lattice).iter().product::<usize>();
            let q: Vec<f64> = (0..n).map(|k| wobble(k, 17, 71)).collect();
            let gq: Vec<f64> = (0..n).map(|k| wobble(k, 29, 83)).collect();
            let vel = tr.velocities(&field, n);
            for dt in [0.05, -0.4, 1.7] {
                let fast = tr.semi_lagrangian(&field, &q, &vel, dt);
                let slow = tr.at_departures(&field, &q, &vel, dt, |s| s.value(&q, &walls));
                assert!(fast
                    .iter()
                    .zip(&slow)
                    .all(|(a, b)| a.to_bits() == b.to_bits()));
                let mut fast_g = Grads::zeros(n, 0, 0);
                let mut fast_v = vec![[0.0; 2]; n];
                tr.semi_lagrangian_vjp(&field, &q, &vel, dt, &gq, &mut fast_g, &mut fast_v);
                let mut slow_g = Grads::zeros(n, 0, 0);
                let mut slow_v = vec![[0.0; 2]; n];
                tr.each_entry(&field, 0, n, |k, _, p| {
                    let dep = Tracer::departure(&field, p, vel[k], dt);
                    dep.scatter(gq[k], &mut slow_g.q, &mut slow_g.walls);
                    let (slx, sly) = dep.slopes(&q, &walls);
                    slow_v[k][0] += -dt / g.dx * gq[k] * slx;
                    slow_v[k][1] += -dt / g.dy * gq[k] * sly;
                });
                assert!(fast_g
                    .q
                    .iter()
                    .zip(&slow_g.q)
                    .all(|(a, b)| a.to_bits() == b.to_bits()));
                let flat =
                    |v: &[[f64; 2]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(flat(&fast_v), flat(&slow_v));
                // the fused step and its product: the bits of the passes
                // with stored velocities
                let lean = field.sampler.periodic().unwrap();
                let fused = tr.periodic_step(&field, lean, &q, dt);
                assert_eq!(bits(&fused), bits(&fast));
                let mut fused_g = Grads::zeros(n, nx, ny);
                tr.periodic_step_vjp(&field, lean, &q, dt, &gq, &mut fused_g);
                let mut passes = Grads::zeros(n, nx, ny);
                let mut g_v = vec![[0.0; 2]; n];
                tr.semi_lagrangian_vjp(&field, &q, &vel, dt, &gq, &mut passes, &mut g_v);
                tr.velocities_vjp(&field, &g_v, &mut passes);
                for (a, b) in [
                    (&fused_g.q, &passes.q),
                    (&fused_g.ux, &passes.ux),
                    (&fused_g.uy, &passes.uy),
                ] {
                    assert_eq!(bits(a), bits(b));
                }
                assert!(passes.ux.iter().any(|&v| v != 0.0));
            }
        }
    }
}
