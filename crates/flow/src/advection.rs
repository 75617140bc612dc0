//! Advection: semi-Lagrangian and MacCormack transport of the staggered
//! velocity by itself, and of passive scalars by the velocity.
//!
//! **Semi-Lagrangian.** Each free entry `q_k` of a field at `x_k` (a face of
//! its component, or a cell centre for a scalar) is traced back along the
//! velocity at `x_k` and the field interpolated there (bilinear on its own
//! lattice, with the side conditions' ghost values beyond the walls):
//!
//! ```text
//! q'_k = I_q(x_k − dt v(x_k)),     v = (I_ux, I_uy)
//! ```
//!
//! **MacCormack** (Selle et al. 2008) corrects the semi-Lagrangian step `A` by
//! the error of a round trip: `q̂ = A q`, `q̃ = A⁻ q̂` (the same step with `−dt`),
//! `q' = q̂ + (q − q̃)/2`, second order in space and time for smooth fields.
//! The limiter clamps `q'` into the range of the four values the forward step
//! interpolated from, which keeps it free of new extrema (and lowers the order
//! where it acts).
//!
//! **Adjoint.** The interpolation is linear in the field and (through the
//! ghosts) in the wall speeds, and piecewise bilinear in the departure point:
//! `∂L/∂q` scatters `g_k` to the four corners with the interpolation weights,
//! and `∂L/∂u` is `g_k ∇I_q(x_dep) · (−dt) ∂v(x_k)/∂u`, scattered with the
//! weights that interpolated `v(x_k)`. A departure point clamped at a boundary
//! does not move with `u` along that axis. MacCormack's adjoint chains those of
//! its two semi-Lagrangian steps; where the limiter clamps, the gradient goes
//! to the corner that was chosen. Fixed faces (walls, inflow, obstacle) are
//! passed through unchanged.
//!
//! # References
//! - J. Stam, *Stable fluids*, SIGGRAPH 1999 (semi-Lagrangian self-advection).
//! - A. Selle, R. Fedkiw, B. Kim, Y. Liu, J. Rossignac, *An unconditionally
//!   stable MacCormack method*, J. Sci. Comput. 35 (2008) 350–371.

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2};

use std::sync::Arc;

use crate::boundaries::{view1, view2, FaceKind, Faces};
use crate::buffers::{
    give_back, in_blocks, join, narrow, scratch, walls_of, wide, zero_pairs, zeros,
};
use crate::grid::{FlowGrid, Lattice};
use crate::sides::Side;
use crate::Result;

/// An advection scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Advection {
    /// First order, unconditionally stable.
    SemiLagrangian,
    /// Second order; `limiter` clamps to the interpolated range.
    MacCormack {
        /// Clamp to the range of the interpolated values.
        limiter: bool,
    },
}

// ---------------------------------------------------------------------------
// Interpolation on a lattice with the side conditions.

/// How one axis of a lattice continues beyond its last entries.
#[derive(Debug, Clone, Copy)]
enum AxisRule {
    /// Clamp to the first and last entries (zero gradient, or the boundary
    /// face itself for the normal velocity).
    Clamp { n: usize },
    /// Wrap around.
    Wrap { n: usize },
    /// A ghost entry at `−1` and at `n`, `factor · u_edge + wall · U_side`.
    Ghost {
        n: usize,
        lo: (f64, f64, usize),
        hi: (f64, f64, usize),
    },
}

/// The two lattice entries bracketing a coordinate along one axis.
#[derive(Debug, Clone, Copy)]
struct Hit {
    idx: [usize; 2],
    factor: [f64; 2],
    wall: [f64; 2],
    side: [usize; 2],
    frac: f64,
    /// Whether the sample moves with the coordinate (false where clamped).
    moves: bool,
    /// Whether both entries are plain lattice values (factor 1, no wall term).
    inside: bool,
}

impl AxisRule {
    #[inline(always)]
    fn hit(self, s: f64) -> Hit {
        let plain = |i0: usize, i1: usize, frac: f64, moves: bool| Hit {
            idx: [i0, i1],
            factor: [1.0, 1.0],
            wall: [0.0, 0.0],
            side: [0, 0],
            frac,
            moves,
            inside: true,
        };
        match self {
            AxisRule::Clamp { n } => {
                if n < 2 {
                    return plain(0, 0, 0.0, false);
                }
                let hi = (n - 1) as f64;
                let moves = s > 0.0 && s < hi;
                let sc = s.clamp(0.0, hi);
                let i0 = (sc.floor() as usize).min(n - 2);
                plain(i0, i0 + 1, sc - i0 as f64, moves)
            }
            AxisRule::Wrap { n } => {
                let (i0, i1, frac) = wrap(s, n);
                plain(i0, i1, frac, true)
            }
            AxisRule::Ghost { n, lo, hi } => {
                let top = n as f64;
                let moves = s > -1.0 && s < top;
                let sc = s.clamp(-1.0, top);
                let i0 = (sc.floor() as i64).min(n as i64 - 1);
                let frac = sc - i0 as f64;
                let entry = |k: i64| -> (usize, f64, f64, usize) {
                    if k < 0 {
                        (0, lo.0, lo.1, lo.2)
                    } else if k >= n as i64 {
                        (n - 1, hi.0, hi.1, hi.2)
                    } else {
                        (k as usize, 1.0, 0.0, 0)
                    }
                };
                let (a, b) = (entry(i0), entry(i0 + 1));
                Hit {
                    idx: [a.0, b.0],
                    factor: [a.1, b.1],
                    wall: [a.2, b.2],
                    side: [a.3, b.3],
                    frac,
                    moves,
                    inside: i0 >= 0 && i0 + 1 < n as i64,
                }
            }
        }
    }
}

/// The entries `(i0, i1)` bracketing `s` on a periodic axis of `n` entries
/// and the fraction of the way from `i0` to `i1`.
#[inline(always)]
fn wrap(s: f64, n: usize) -> (usize, usize, f64) {
    let fl = s.floor();
    // one wrap covers any Courant number below n; no division then
    let mut i0 = fl as i64;
    let n64 = n as i64;
    if i0 < 0 {
        i0 += n64;
    } else if i0 >= n64 {
        i0 -= n64;
    }
    if !(0..n64).contains(&i0) {
        i0 = i0.rem_euclid(n64);
    }
    let i0 = i0 as usize;
    let i1 = if i0 + 1 == n { 0 } else { i0 + 1 };
    (i0, i1, s - fl)
}

/// The bilinear value of the corner values `v` with the weights `wx`, `wy`
/// along x and y: the one formula every interpolation here uses.
#[inline(always)]
fn bilinear(v: [[f64; 2]; 2], wx: [f64; 2], wy: [f64; 2]) -> f64 {
    wx[0] * (wy[0] * v[0][0] + wy[1] * v[0][1]) + wx[1] * (wy[0] * v[1][0] + wy[1] * v[1][1])
}

/// `∂ bilinear / ∂s` along x and along y, in lattice units.
#[inline(always)]
fn bilinear_slopes(v: [[f64; 2]; 2], wx: [f64; 2], wy: [f64; 2]) -> (f64, f64) {
    (
        wy[0] * (v[1][0] - v[0][0]) + wy[1] * (v[1][1] - v[0][1]),
        wx[0] * (v[0][1] - v[0][0]) + wx[1] * (v[1][1] - v[1][0]),
    )
}

/// The values of `u` at the plain lattice entries `k`.
#[inline(always)]
fn corner_values(u: &[f64], k: [[usize; 2]; 2]) -> [[f64; 2]; 2] {
    [[u[k[0][0]], u[k[0][1]]], [u[k[1][0]], u[k[1][1]]]]
}

/// Adds `c · wx[a] · wy[b]` to the plain lattice entry `k[a][b]` (the
/// transpose of [`bilinear`]), corners in the order `Stencil::scatter` takes.
#[inline(always)]
fn bilinear_scatter(k: [[usize; 2]; 2], wx: [f64; 2], wy: [f64; 2], c: f64, grad: &mut [f64]) {
    for (ka, wa) in k.iter().zip(wx) {
        for (&kab, wb) in ka.iter().zip(wy) {
            grad[kab] += c * wa * wb;
        }
    }
}

/// Four plain lattice entries `[[k00, k01], [k10, k11]]` and the bilinear
/// weights along x and y.
type PlainCorners = ([[usize; 2]; 2], [f64; 2], [f64; 2]);

/// A sampler both of whose axes wrap (a periodic box): every corner is a
/// plain lattice value, so a departure point needs only its two brackets per
/// axis. The arithmetic is [`Sampler::locate`]'s and [`Stencil`]'s, term for
/// term, so the same bits.
#[derive(Debug, Clone, Copy)]
struct Periodic {
    n: [usize; 2],
    h: (f64, f64),
    offsets: (f64, f64),
}

impl Periodic {
    /// The corners' indices `[[k00, k01], [k10, k11]]` and the weights along
    /// x and y of the point `p`.
    #[inline(always)]
    fn locate(&self, p: [f64; 2]) -> PlainCorners {
        let (i0, i1, fx) = wrap(p[0] / self.h.0 - self.offsets.0, self.n[0]);
        let (j0, j1, fy) = wrap(p[1] / self.h.1 - self.offsets.1, self.n[1]);
        let nb = self.n[1];
        (
            [[i0 * nb + j0, i0 * nb + j1], [i1 * nb + j0, i1 * nb + j1]],
            [1.0 - fx, fx],
            [1.0 - fy, fy],
        )
    }
}

/// Bilinear interpolation of the arrays of one lattice.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sampler {
    rx: AxisRule,
    ry: AxisRule,
    offsets: (f64, f64),
    h: (f64, f64),
    nb: usize,
}

/// Where a sample reads: the corners along x and y.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stencil {
    hx: Hit,
    hy: Hit,
    nb: usize,
    /// Every corner is a plain lattice value (the common case, away from
    /// the walls): `corner` is a load and `scatter_corner` one add.
    inside: bool,
}

impl Sampler {
    pub(crate) fn new(grid: &FlowGrid, lattice: Lattice) -> Self {
        let sides = &grid.sides;
        let ghost = |lo: Side, hi: Side, n: usize| {
            let (fl, wl) = sides.get(lo).ghost();
            let (fh, wh) = sides.get(hi).ghost();
            AxisRule::Ghost {
                n,
                lo: (fl, wl, lo.index()),
                hi: (fh, wh, hi.index()),
            }
        };
        let (px, py) = (grid.periodic_x(), grid.periodic_y());
        let [na, nb] = grid.shape(lattice);
        let rx = match (lattice, px) {
            (_, true) => AxisRule::Wrap { n: na },
            (Lattice::FaceY, false) => ghost(Side::Left, Side::Right, na),
            _ => AxisRule::Clamp { n: na },
        };
        let ry = match (lattice, py) {
            (_, true) => AxisRule::Wrap { n: nb },
            (Lattice::FaceX, false) => ghost(Side::Bottom, Side::Top, nb),
            _ => AxisRule::Clamp { n: nb },
        };
        Sampler {
            rx,
            ry,
            offsets: lattice.offsets(),
            h: (grid.dx, grid.dy),
            nb,
        }
    }

    /// The sampler's lean form when both axes wrap.
    fn periodic(&self) -> Option<Periodic> {
        match (self.rx, self.ry) {
            (AxisRule::Wrap { n: na }, AxisRule::Wrap { n: nb }) => Some(Periodic {
                n: [na, nb],
                h: self.h,
                offsets: self.offsets,
            }),
            _ => None,
        }
    }

    /// The stencil of the point `p`.
    #[inline(always)]
    pub(crate) fn locate(&self, p: [f64; 2]) -> Stencil {
        // a division, not a product with 1/h: a point on the lattice
        // lands on its entry exactly (no motion is the identity)
        let hx = self.rx.hit(p[0] / self.h.0 - self.offsets.0);
        let hy = self.ry.hit(p[1] / self.h.1 - self.offsets.1);
        Stencil {
            hx,
            hy,
            nb: self.nb,
            inside: hx.inside && hy.inside,
        }
    }
}

/// A sampler's stencils at the entries of a lattice, by axis: the position of
/// entry `(a, b)` is `((a + o_a) dx, (b + o_b) dy)`, so `locate` of it is
/// `along_x[a]` by `along_y[b]` (the same hits, computed once per axis).
struct LatticeStencils {
    along_x: Vec<Hit>,
    along_y: Vec<Hit>,
    nb: usize,
}

impl LatticeStencils {
    /// The plain lattice entries and the weights of entry `(a, b)`'s
    /// stencil where all four corners are plain values (no ghost, no wall).
    #[inline(always)]
    fn plain(&self, [a, b]: [usize; 2]) -> Option<PlainCorners> {
        let (hx, hy) = (&self.along_x[a], &self.along_y[b]);
        if !(hx.inside && hy.inside) {
            return None;
        }
        let (r0, r1) = (hx.idx[0] * self.nb, hx.idx[1] * self.nb);
        let (j0, j1) = (hy.idx[0], hy.idx[1]);
        Some((
            [[r0 + j0, r0 + j1], [r1 + j0, r1 + j1]],
            Stencil::weights(hx),
            Stencil::weights(hy),
        ))
    }

    /// `at(ab).value(u, walls)`, without building the stencil where its
    /// corners are plain (the same arithmetic, so the same bits).
    #[inline(always)]
    fn value_at(&self, ab: [usize; 2], u: &[f64], walls: &[f64; 4]) -> f64 {
        match self.plain(ab) {
            Some((k, wx, wy)) => bilinear(corner_values(u, k), wx, wy),
            None => self.at(ab).value(u, walls),
        }
    }

    /// `at(ab).scatter(c, grad_u, grad_walls)`, without building the stencil
    /// where its corners are plain (the same arithmetic, so the same bits).
    #[inline(always)]
    fn scatter_at(&self, ab: [usize; 2], c: f64, grad_u: &mut [f64], grad_walls: &mut [f64; 4]) {
        match self.plain(ab) {
            Some((k, wx, wy)) => bilinear_scatter(k, wx, wy, c, grad_u),
            None => self.at(ab).scatter(c, grad_u, grad_walls),
        }
    }

    /// The stencil of entry `(a, b)`: the one `locate` gives at its position.
    #[inline(always)]
    fn at(&self, [a, b]: [usize; 2]) -> Stencil {
        let (hx, hy) = (self.along_x[a], self.along_y[b]);
        Stencil {
            hx,
            hy,
            nb: self.nb,
            inside: hx.inside && hy.inside,
        }
    }
}

impl Sampler {
    /// The stencils of this sampler at every entry of `lattice`.
    fn on_lattice(&self, grid: &FlowGrid, lattice: Lattice) -> LatticeStencils {
        let [na, nb] = grid.shape(lattice);
        let (oa, ob) = lattice.offsets();
        LatticeStencils {
            along_x: (0..na)
                .map(|a| {
                    self.rx
                        .hit((a as f64 + oa) * grid.dx / self.h.0 - self.offsets.0)
                })
                .collect(),
            along_y: (0..nb)
                .map(|b| {
                    self.ry
                        .hit((b as f64 + ob) * grid.dy / self.h.1 - self.offsets.1)
                })
                .collect(),
            nb: self.nb,
        }
    }
}

impl Stencil {
    #[inline(always)]
    fn weights(h: &Hit) -> [f64; 2] {
        [1.0 - h.frac, h.frac]
    }

    /// The corner value `(a, b)` with its ghost factors.
    #[inline(always)]
    fn corner(&self, a: usize, b: usize, u: &[f64], walls: &[f64; 4]) -> f64 {
        let k = self.hx.idx[a] * self.nb + self.hy.idx[b];
        if self.inside {
            return u[k];
        }
        self.hx.factor[a] * self.hy.factor[b] * u[k]
            + self.hx.wall[a] * walls[self.hx.side[a]]
            + self.hy.wall[b] * walls[self.hy.side[b]]
    }

    #[inline(always)]
    fn corners(&self, u: &[f64], walls: &[f64; 4]) -> [[f64; 2]; 2] {
        [
            [self.corner(0, 0, u, walls), self.corner(0, 1, u, walls)],
            [self.corner(1, 0, u, walls), self.corner(1, 1, u, walls)],
        ]
    }

    /// The interpolated value.
    #[inline(always)]
    pub(crate) fn value(&self, u: &[f64], walls: &[f64; 4]) -> f64 {
        let (wx, wy) = (Self::weights(&self.hx), Self::weights(&self.hy));
        bilinear(self.corners(u, walls), wx, wy)
    }

    /// `∂value/∂s` along x and y in lattice units (zero where clamped).
    #[inline(always)]
    fn slopes(&self, u: &[f64], walls: &[f64; 4]) -> (f64, f64) {
        let (wx, wy) = (Self::weights(&self.hx), Self::weights(&self.hy));
        let (sx, sy) = bilinear_slopes(self.corners(u, walls), wx, wy);
        (
            if self.hx.moves { sx } else { 0.0 },
            if self.hy.moves { sy } else { 0.0 },
        )
    }

    /// Adds `c · ∂value/∂u` to `grad_u` and `c · ∂value/∂U` to `grad_walls`.
    #[inline(always)]
    pub(crate) fn scatter(&self, c: f64, grad_u: &mut [f64], grad_walls: &mut [f64; 4]) {
        let (wx, wy) = (Self::weights(&self.hx), Self::weights(&self.hy));
        for (a, wa) in wx.iter().enumerate() {
            for (b, wb) in wy.iter().enumerate() {
                self.scatter_corner(a, b, c * wa * wb, grad_u, grad_walls);
            }
        }
    }

    #[inline(always)]
    fn scatter_corner(
        &self,
        a: usize,
        b: usize,
        c: f64,
        grad_u: &mut [f64],
        grad_walls: &mut [f64; 4],
    ) {
        let k = self.hx.idx[a] * self.nb + self.hy.idx[b];
        if self.inside {
            grad_u[k] += c;
            return;
        }
        grad_u[k] += c * self.hx.factor[a] * self.hy.factor[b];
        // most corners are inside: no wall term, and no store to the walls
        // that would chain every scatter through memory
        if self.hx.wall[a] != 0.0 {
            grad_walls[self.hx.side[a]] += c * self.hx.wall[a];
        }
        if self.hy.wall[b] != 0.0 {
            grad_walls[self.hy.side[b]] += c * self.hy.wall[b];
        }
    }

    /// The interpolated value (as [`Stencil::value`]) and the smallest and
    /// largest of the four corner values (those of [`Stencil::extremes`]).
    #[inline(always)]
    fn value_and_range(&self, u: &[f64], walls: &[f64; 4]) -> (f64, [f64; 2]) {
        let v = self.corners(u, walls);
        let (wx, wy) = (Self::weights(&self.hx), Self::weights(&self.hy));
        let value = bilinear(v, wx, wy);
        let lo = v[0][0].min(v[0][1]).min(v[1][0]).min(v[1][1]);
        let hi = v[0][0].max(v[0][1]).max(v[1][0]).max(v[1][1]);
        (value, [lo, hi])
    }

    /// The corner holding the smallest and the largest value.
    #[inline(always)]
    fn extremes(&self, u: &[f64], walls: &[f64; 4]) -> ((usize, usize, f64), (usize, usize, f64)) {
        let v = self.corners(u, walls);
        let mut lo = (0, 0, v[0][0]);
        let mut hi = lo;
        for (a, row) in v.iter().enumerate() {
            for (b, &x) in row.iter().enumerate() {
                if x < lo.2 {
                    lo = (a, b, x);
                }
                if x > hi.2 {
                    hi = (a, b, x);
                }
            }
        }
        (lo, hi)
    }
}

// ---------------------------------------------------------------------------
// Semi-Lagrangian and MacCormack steps of one field.

/// The velocity field a step traces with.
struct Tracer<'a> {
    grid: &'a FlowGrid,
    ux: &'a [f64],
    uy: &'a [f64],
    walls: [f64; 4],
    sx: Sampler,
    sy: Sampler,
}

/// One field being advected: its lattice, sampler and free entries.
struct Field<'a> {
    lattice: Lattice,
    sampler: Sampler,
    kinds: &'a [FaceKind],
}

impl Field<'_> {
    fn free(&self, k: usize) -> bool {
        self.kinds.get(k).is_none_or(|kind| *kind == FaceKind::Free)
    }
}

/// Entries per block of the loops that compute each entry on its own; the
/// blocks run on all cores from [`PARALLEL_FROM`] entries. Every entry is
/// computed by the same arithmetic wherever it runs, so the results do not
/// depend on the number of threads.
const BLOCK: usize = 1024;

/// The number of entries from which the per-entry loops use all cores (an
/// entry costs a few bilinear interpolations, about a hundred times a CG
/// kernel's element).
pub(crate) const PARALLEL_FROM: usize = 8192;

/// Runs `f(offset, block)` on the [`BLOCK`]-sized blocks of `out`.
fn for_blocks<V: Send>(out: &mut [V], f: impl Fn(usize, &mut [V]) + Sync + Send) {
    let split = out.len() >= PARALLEL_FROM && rayon::current_num_threads() > 1;
    in_blocks(out, BLOCK, split, f);
}

impl Tracer<'_> {
    /// Runs `f(k, [a, b], x_k)` on the entries `off..off + len` of `field` in
    /// order, `(a, b)` the entry's index and `x_k` its position (as
    /// [`FlowGrid::position`], without a division per entry).
    fn each_entry(
        &self,
        field: &Field<'_>,
        off: usize,
        len: usize,
        mut f: impl FnMut(usize, [usize; 2], [f64; 2]),
    ) {
        let nb = field.sampler.nb;
        let (oa, ob) = field.lattice.offsets();
        let (dx, dy) = (self.grid.dx, self.grid.dy);
        let (mut a, mut b) = (off / nb, off % nb);
        for k in off..off + len {
            f(k, [a, b], [(a as f64 + oa) * dx, (b as f64 + ob) * dy]);
            b += 1;
            if b == nb {
                b = 0;
                a += 1;
            }
        }
    }

    /// `v(x_k) = (I_ux(x_k), I_uy(x_k))` at every free entry of `field`
    /// (zero at fixed entries, which are not traced). Computed once per step
    /// and shared by its passes; the stencils come from the per-axis tables
    /// of [`Sampler::on_lattice`]. On a face lattice the component that lives
    /// there is read, not interpolated: `I_ux` at an x-face is `u_x` there
    /// (the bilinear weights of a lattice point are 1 and 0 up to rounding).
    fn velocities(&self, field: &Field<'_>, len: usize) -> Vec<[f64; 2]> {
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
    fn tables(&self, lattice: Lattice) -> [LatticeStencils; 2] {
        [
            self.sx.on_lattice(self.grid, lattice),
            self.sy.on_lattice(self.grid, lattice),
        ]
    }

    /// [`Tracer::velocities`] at the free entry `k`, `(a, b)`, of a field on
    /// `own`, from its [`Tracer::tables`].
    #[inline(always)]
    fn velocity_at(
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
    fn velocities_vjp(&self, field: &Field<'_>, g_v: &[[f64; 2]], grads: &mut Grads) {
        let tables = self.tables(field.lattice);
        self.each_entry(field, 0, g_v.len(), |k, ab, _| {
            self.velocity_vjp_at(field.lattice, &tables, k, ab, g_v[k], grads);
        });
    }

    /// The adjoint of [`Tracer::velocity_at`] with `g` (the gradient of the
    /// entry's velocity), added to `grads`.
    #[inline(always)]
    fn velocity_vjp_at(
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

    /// A semi-Lagrangian step on a periodic box (`lean`, the field's
    /// sampler): each entry's tracing velocity computed where it is used,
    /// not stored. The arithmetic of [`Tracer::velocities`] and
    /// [`Tracer::semi_lagrangian`], so the same bits.
    fn periodic_step(&self, field: &Field<'_>, lean: Periodic, q: &[f64], dt: f64) -> Vec<f64> {
        let tables = self.tables(field.lattice);
        // every entry is written
        let mut out = scratch(q.len());
        for_blocks(&mut out, |off, block| {
            self.each_entry(field, off, block.len(), |k, ab, p| {
                block[k - off] = if field.free(k) {
                    let v = self.velocity_at(field.lattice, &tables, k, ab);
                    let (c, wx, wy) = lean.locate([p[0] - dt * v[0], p[1] - dt * v[1]]);
                    bilinear(corner_values(q, c), wx, wy)
                } else {
                    q[k]
                };
            });
        });
        out
    }

    /// The vector–Jacobian product of [`Tracer::periodic_step`] with `g`,
    /// added to `grads`: [`Tracer::semi_lagrangian_vjp`] and
    /// [`Tracer::velocities_vjp`] in one pass, without the velocities' and
    /// their gradient's arrays. The velocity gradients are added in entry
    /// order as there, and the field's go to another array: the same bits.
    fn periodic_step_vjp(
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
    fn each_gradient(
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
    fn departure(field: &Field<'_>, p: [f64; 2], v: [f64; 2], dt: f64) -> Stencil {
        field.sampler.locate([p[0] - dt * v[0], p[1] - dt * v[1]])
    }

    /// `at(stencil)` of the departure stencil over `dt` at every free entry of
    /// `field` (traced by `vel`), `fixed(k)` at the fixed entries.
    fn at_departures<V: Send>(
        &self,
        field: &Field<'_>,
        vel: &[[f64; 2]],
        dt: f64,
        fixed: impl Fn(usize) -> V,
        at: impl Fn(Stencil) -> V + Sync + Send,
    ) -> Vec<V> {
        let mut out: Vec<V> = (0..vel.len()).map(fixed).collect();
        for_blocks(&mut out, |off, block| {
            self.each_entry(field, off, block.len(), |k, _, p| {
                if field.free(k) {
                    block[k - off] = at(Self::departure(field, p, vel[k], dt));
                }
            });
        });
        out
    }

    /// `A q`: one semi-Lagrangian step of `q` with the tracing velocities
    /// `vel` (fixed entries copied).
    fn semi_lagrangian(&self, field: &Field<'_>, q: &[f64], vel: &[[f64; 2]], dt: f64) -> Vec<f64> {
        let Some(lean) = field.sampler.periodic() else {
            return self.at_departures(field, vel, dt, |k| q[k], |s| s.value(q, &self.walls));
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
    fn semi_lagrangian_ranged(
        &self,
        field: &Field<'_>,
        q: &[f64],
        vel: &[[f64; 2]],
        dt: f64,
    ) -> (Vec<f64>, Vec<[f64; 2]>) {
        let out = self.at_departures(
            field,
            vel,
            dt,
            |k| (q[k], [q[k]; 2]),
            |s| s.value_and_range(q, &self.walls),
        );
        out.into_iter().unzip()
    }

    /// `q̂ = A q`, with the limiter's range where `limiter` is on (else empty).
    fn first_pass(
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
    fn semi_lagrangian_vjp(
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
    fn periodic_entry_vjp(
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
    fn slope_factors(&self, dt: f64) -> [f64; 2] {
        [-dt / self.grid.dx, -dt / self.grid.dy]
    }

    /// One step of `scheme`.
    fn step(&self, field: &Field<'_>, q: &[f64], dt: f64, scheme: Advection) -> Vec<f64> {
        if let (Advection::SemiLagrangian, Some(lean)) = (scheme, field.sampler.periodic()) {
            return self.periodic_step(field, lean, q, dt);
        }
        let vel = self.velocities(field, q.len());
        let Advection::MacCormack { limiter } = scheme else {
            let out = self.semi_lagrangian(field, q, &vel, dt);
            give_back(vel);
            return out;
        };
        let (qh, range) = self.first_pass(field, q, &vel, dt, limiter);
        let qt = self.semi_lagrangian(field, &qh, &vel, -dt);
        let mut out = qh.clone();
        for_blocks(&mut out, |off, block| {
            for (i, o) in block.iter_mut().enumerate() {
                let k = off + i;
                if !field.free(k) {
                    continue;
                }
                let v = qh[k] + 0.5 * (q[k] - qt[k]);
                *o = if limiter {
                    v.clamp(range[k][0], range[k][1])
                } else {
                    v
                };
            }
        });
        give_back(vel);
        give_back(qh);
        give_back(qt);
        out
    }

    /// Adds the vector–Jacobian product of [`Tracer::step`] to `grads`.
    fn step_vjp(
        &self,
        field: &Field<'_>,
        q: &[f64],
        dt: f64,
        scheme: Advection,
        g: &[f64],
        grads: &mut Grads,
    ) {
        if let (Advection::SemiLagrangian, Some(lean)) = (scheme, field.sampler.periodic()) {
            self.periodic_step_vjp(field, lean, q, dt, g, grads);
            return;
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
        let (qh, range) = self.first_pass(field, q, &vel, dt, limiter);
        let qt = self.semi_lagrangian(field, &qh, &vel, -dt);
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
                    // clamped: the gradient goes to the corner that was chosen
                    let dep = Self::departure(field, p, vel[k], dt);
                    let (lo, hi) = dep.extremes(q, &self.walls);
                    let (a, b, _) = if v < lo.2 { lo } else { hi };
                    dep.scatter_corner(a, b, gk, &mut grads.q, &mut grads.walls);
                    return;
                }
            }
            g_hat[k] += gk;
            grads.q[k] += 0.5 * gk;
            g_tilde[k] = -0.5 * gk;
        });
        // q̃ = A⁻ q̂: its field gradient lands on q̂.
        let mut inner = Grads::zeros(n, 0, 0);
        self.semi_lagrangian_vjp(field, &qh, &vel, -dt, &g_tilde, &mut inner, &mut g_v);
        for (a, b) in g_hat.iter_mut().zip(&inner.q) {
            *a += b;
        }
        inner.q.iter_mut().for_each(|v| *v = 0.0);
        // q̂ = A q.
        self.semi_lagrangian_vjp(field, q, &vel, dt, &g_hat, &mut inner, &mut g_v);
        grads.add(&inner);
        self.velocities_vjp(field, &g_v, grads);
        for v in [qh, qt, g_hat, g_tilde, inner.q, inner.ux, inner.uy] {
            give_back(v);
        }
        give_back(vel);
        give_back(g_v);
    }
}

/// Gradients of one advected field and of the velocity that carries it.
struct Grads {
    q: Vec<f64>,
    ux: Vec<f64>,
    uy: Vec<f64>,
    walls: [f64; 4],
}

impl Grads {
    fn zeros(nq: usize, nx: usize, ny: usize) -> Self {
        Grads {
            q: zeros(nq),
            ux: zeros(nx),
            uy: zeros(ny),
            walls: [0.0; 4],
        }
    }

    /// Adds `o` (whose velocity gradients may be empty: none).
    fn add(&mut self, o: &Grads) {
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

fn field_of<'a>(grid: &FlowGrid, faces: &'a Faces, lattice: Lattice) -> Field<'a> {
    Field {
        lattice,
        sampler: Sampler::new(grid, lattice),
        kinds: faces.of(lattice),
    }
}

fn tracer<'a>(grid: &'a FlowGrid, ux: &'a [f64], uy: &'a [f64], walls: [f64; 4]) -> Tracer<'a> {
    Tracer {
        grid,
        ux,
        uy,
        walls,
        sx: Sampler::new(grid, Lattice::FaceX),
        sy: Sampler::new(grid, Lattice::FaceY),
    }
}

/// The gradients of [`advect_velocity`].
#[derive(Debug, Clone, PartialEq)]
pub struct VelocityAdvectionGrads<T> {
    /// `∂L/∂q_x`.
    pub field_x: Array2<T>,
    /// `∂L/∂q_y`.
    pub field_y: Array2<T>,
    /// `∂L/∂u_x`.
    pub ux: Array2<T>,
    /// `∂L/∂u_y`.
    pub uy: Array2<T>,
    /// `∂L/∂U` of the four wall speeds.
    pub wall_speed: Array1<T>,
}

/// The gradients of [`advect_scalar`].
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarAdvectionGrads<T> {
    /// `∂L/∂s`.
    pub scalar: Array2<T>,
    /// `∂L/∂u_x`.
    pub ux: Array2<T>,
    /// `∂L/∂u_y`.
    pub uy: Array2<T>,
    /// `∂L/∂U` of the four wall speeds.
    pub wall_speed: Array1<T>,
}

const VELOCITY: &str = "velocity advection";
const SCALAR: &str = "scalar advection";

/// Advection of the staggered field `(q_x, q_y)` by `scheme` over `dt`,
/// traced by the velocity `(u_x, u_y)`: each component becomes `A q` (see the
/// [module docs](self)); `wall_speed` holds the four wall speeds `U`.
/// Self-advection passes the velocity as both; the incremental splitting
/// advects `u − (dt/2)∇P` traced by `u`.
///
/// # Errors
/// [`crate::FlowError::Shape`] for arrays of the wrong shapes.
pub fn advect_velocity<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    scheme: Advection,
    dt: f64,
    field: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    velocity: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    wall_speed: ArrayView1<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    grid.check_velocity(VELOCITY, field.0, field.1)?;
    grid.check_velocity(VELOCITY, velocity.0, velocity.1)?;
    grid.check_walls(VELOCITY, wall_speed)?;
    let (ux, uy) = (wide(velocity.0), wide(velocity.1));
    let tr = tracer(grid, &ux, &uy, walls_of(wall_speed));
    let g = grid;
    // the two components are independent: on two threads when there are
    let (ox, oy) = join(
        || {
            tr.step(
                &field_of(grid, faces, Lattice::FaceX),
                &wide(field.0),
                dt,
                scheme,
            )
        },
        || {
            tr.step(
                &field_of(grid, faces, Lattice::FaceY),
                &wide(field.1),
                dt,
                scheme,
            )
        },
    );
    Ok((narrow(g.shape_x(), ox), narrow(g.shape_y(), oy)))
}

/// The vector–Jacobian product of [`advect_velocity`] with the gradients
/// `grad_x`, `grad_y` of its outputs.
///
/// # Errors
/// As [`advect_velocity`].
#[allow(clippy::too_many_arguments)]
pub fn advect_velocity_vjp<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    scheme: Advection,
    dt: f64,
    field: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    velocity: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    wall_speed: ArrayView1<'_, T>,
    grad: (ArrayView2<'_, T>, ArrayView2<'_, T>),
) -> Result<VelocityAdvectionGrads<T>> {
    grid.check_velocity(VELOCITY, field.0, field.1)?;
    grid.check_velocity(VELOCITY, velocity.0, velocity.1)?;
    grid.check_velocity(VELOCITY, grad.0, grad.1)?;
    grid.check_walls(VELOCITY, wall_speed)?;
    let (ux, uy) = (wide(velocity.0), wide(velocity.1));
    let tr = tracer(grid, &ux, &uy, walls_of(wall_speed));
    let (nx, ny) = (ux.len(), uy.len());
    // each component's products land in gradients of its own, added after
    // in a fixed order: on two threads, the same bits as on one
    let component = |lattice: Lattice, q: ArrayView2<'_, T>, g: ArrayView2<'_, T>, nq: usize| {
        let mut grads = Grads::zeros(nq, nx, ny);
        tr.step_vjp(
            &field_of(grid, faces, lattice),
            &wide(q),
            dt,
            scheme,
            &wide(g),
            &mut grads,
        );
        grads
    };
    let (mut gx, gy) = join(
        || component(Lattice::FaceX, field.0, grad.0, nx),
        || component(Lattice::FaceY, field.1, grad.1, ny),
    );
    // the velocity traces both components
    for (a, b) in [(&mut gx.ux, &gy.ux), (&mut gx.uy, &gy.uy)] {
        a.iter_mut().zip(b.iter()).for_each(|(x, y)| *x += y);
    }
    give_back(gy.ux);
    give_back(gy.uy);
    let g = grid;
    Ok(VelocityAdvectionGrads {
        field_x: narrow(g.shape_x(), gx.q),
        field_y: narrow(g.shape_y(), gy.q),
        ux: narrow(g.shape_x(), gx.ux),
        uy: narrow(g.shape_y(), gx.uy),
        wall_speed: (0..4)
            .map(|s| T::from_f64(gx.walls[s] + gy.walls[s]))
            .collect(),
    })
}

/// Advection of a cell-centred scalar `s` by the velocity over `dt`
/// (zero-gradient beyond non-periodic sides).
///
/// # Errors
/// [`FlowError::Shape`] for arrays of the wrong shapes.
#[allow(clippy::too_many_arguments)]
pub fn advect_scalar<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    scheme: Advection,
    dt: f64,
    s: ArrayView2<'_, T>,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    wall_speed: ArrayView1<'_, T>,
) -> Result<Array2<T>> {
    grid.check_velocity(SCALAR, ux, uy)?;
    grid.check_cells(SCALAR, "scalar", s)?;
    grid.check_walls(SCALAR, wall_speed)?;
    let (ux, uy) = (wide(ux), wide(uy));
    let tr = tracer(grid, &ux, &uy, walls_of(wall_speed));
    let out = tr.step(&field_of(grid, faces, Lattice::Cell), &wide(s), dt, scheme);
    Ok(narrow(grid.cell_shape(), out))
}

/// The vector–Jacobian product of [`advect_scalar`] with the gradient `grad`
/// of its output.
///
/// # Errors
/// As [`advect_scalar`].
#[allow(clippy::too_many_arguments)]
pub fn advect_scalar_vjp<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    scheme: Advection,
    dt: f64,
    s: ArrayView2<'_, T>,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    wall_speed: ArrayView1<'_, T>,
    grad: ArrayView2<'_, T>,
) -> Result<ScalarAdvectionGrads<T>> {
    grid.check_velocity(SCALAR, ux, uy)?;
    grid.check_cells(SCALAR, "scalar", s)?;
    grid.check_cells(SCALAR, "gradient", grad)?;
    grid.check_walls(SCALAR, wall_speed)?;
    let (uxw, uyw) = (wide(ux), wide(uy));
    let tr = tracer(grid, &uxw, &uyw, walls_of(wall_speed));
    let sw = wide(s);
    let mut g = Grads::zeros(sw.len(), uxw.len(), uyw.len());
    tr.step_vjp(
        &field_of(grid, faces, Lattice::Cell),
        &sw,
        dt,
        scheme,
        &wide(grad),
        &mut g,
    );
    Ok(ScalarAdvectionGrads {
        scalar: narrow(grid.cell_shape(), g.q),
        ux: narrow(grid.shape_x(), g.ux),
        uy: narrow(grid.shape_y(), g.uy),
        wall_speed: (0..4).map(|s| T::from_f64(g.walls[s])).collect(),
    })
}

/// [`advect_velocity`] as a tape op: inputs `[q_x, q_y, u_x, u_y,
/// wall_speed]`, outputs `[q_x', q_y']`.
#[derive(Debug, Clone)]
pub struct AdvectVelocity {
    /// The grid.
    pub grid: FlowGrid,
    /// Its faces: fixed ones are passed through.
    pub faces: Arc<Faces>,
    /// The scheme.
    pub scheme: Advection,
    /// The time step.
    pub dt: f64,
}

impl<T: Real> Op<T> for AdvectVelocity {
    fn name(&self) -> &str {
        VELOCITY
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(VELOCITY, 5, inputs.len())?;
        let (a, b) = advect_velocity(
            &self.grid,
            &self.faces,
            self.scheme,
            self.dt,
            (view2(&inputs[0])?, view2(&inputs[1])?),
            (view2(&inputs[2])?, view2(&inputs[3])?),
            view1(&inputs[4])?,
        )?;
        Ok(vec![a.into_dyn(), b.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let gx = args.grad_output_or_zeros(0);
        let gy = args.grad_output_or_zeros(1);
        let g = advect_velocity_vjp(
            &self.grid,
            &self.faces,
            self.scheme,
            self.dt,
            (view2(args.input(0))?, view2(args.input(1))?),
            (view2(args.input(2))?, view2(args.input(3))?),
            view1(args.input(4))?,
            (view2(&gx.view())?, view2(&gy.view())?),
        )?;
        Ok(vec![
            args.needs(0).then(|| g.field_x.into_dyn()),
            args.needs(1).then(|| g.field_y.into_dyn()),
            args.needs(2).then(|| g.ux.into_dyn()),
            args.needs(3).then(|| g.uy.into_dyn()),
            args.needs(4).then(|| g.wall_speed.into_dyn()),
        ])
    }
}

/// [`advect_scalar`] as a tape op: inputs `[s, u_x, u_y, wall_speed]`,
/// output `[s']`.
#[derive(Debug, Clone)]
pub struct AdvectScalar {
    /// The grid.
    pub grid: FlowGrid,
    /// Its faces: fixed ones are passed through.
    pub faces: Arc<Faces>,
    /// The scheme.
    pub scheme: Advection,
    /// The time step.
    pub dt: f64,
}

impl<T: Real> Op<T> for AdvectScalar {
    fn name(&self) -> &str {
        SCALAR
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(SCALAR, 4, inputs.len())?;
        let s = advect_scalar(
            &self.grid,
            &self.faces,
            self.scheme,
            self.dt,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
            view2(&inputs[2])?,
            view1(&inputs[3])?,
        )?;
        Ok(vec![s.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let g = advect_scalar_vjp(
            &self.grid,
            &self.faces,
            self.scheme,
            self.dt,
            view2(args.input(0))?,
            view2(args.input(1))?,
            view2(args.input(2))?,
            view1(args.input(3))?,
            view2(args.grad_out())?,
        )?;
        Ok(vec![
            args.needs(0).then(|| g.scalar.into_dyn()),
            args.needs(1).then(|| g.ux.into_dyn()),
            args.needs(2).then(|| g.uy.into_dyn()),
            args.needs(3).then(|| g.wall_speed.into_dyn()),
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
        let (grid, faces) = grid_and_faces(13, 9, [1.3, 0.7], Sides::periodic());
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
                let slow = tr.at_departures(&field, &vel, dt, |k| q[k], |s| s.value(&q, &walls));
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
