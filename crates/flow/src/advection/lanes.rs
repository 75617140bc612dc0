//! The periodic box's advection a row segment at a time: the same arithmetic
//! as the entry-by-entry loops, laid out so the compiler vectorises it.
//!
//! An interpolation at a departure point is a division and a subtraction per
//! axis (the point in lattice units), a wrap and four loads (the corners),
//! then the bilinear weights and sum. Done one entry at a time, all of it
//! runs in scalar `f64`. Here up to [`SEGMENT`] neighbouring entries of one
//! row go through each phase together, each phase a loop of its own over
//! arrays: the departure points' lattice coordinates (vector divisions), the
//! floors, fractions and wraps (vector rounding and compares), the corners'
//! indices (vector integer arithmetic), the loads (one by one), then the
//! weights and sums (vector products). Each entry is computed by the
//! operations the entry-by-entry code applies to it, in the same order (Rust
//! never fuses a product into a sum, and the divisions stay divisions), so
//! the results are the same bits; the unit tests of the MacCormack sweeps and
//! of the periodic step hold them to the scalar passes.

use std::cell::RefCell;

use super::sampling::{wrap, LatticeStencils, Periodic, Stencil};
use super::tracer::{Field, Tracer};
use crate::grid::Lattice;

/// Entries of one row computed together: long enough for the loops over
/// them to run in vector registers, short enough for their arrays (a few
/// kilobytes) to stay in the L1 cache.
pub(super) const SEGMENT: usize = 64;

/// One value per entry of a segment.
pub(super) type Segment<V = f64> = [V; SEGMENT];

/// The arrays a segment's loops write: filled segment after segment, and
/// kept by each thread from one call to the next (zeroing them for every
/// block of entries cost about as much as a tenth of the work).
pub(super) struct Workspace {
    pub(super) departures: Departures,
    pub(super) corners: Corners,
    /// The tracing velocity of the segment's entries.
    pub(super) v: [Segment; 2],
    /// Values by entry: the results, the limiter's range.
    pub(super) out: [Segment; 3],
}

thread_local! {
    static WORKSPACE: RefCell<Box<Workspace>> = RefCell::new(Box::new(Workspace {
        departures: Departures::default(),
        corners: Corners::default(),
        v: [[0.0; SEGMENT]; 2],
        out: [[0.0; SEGMENT]; 3],
    }));
}

/// `f` with this thread's [`Workspace`].
///
/// # Panics
/// If `f` calls it again (the loops here never do).
pub(super) fn with_workspace<R>(f: impl FnOnce(&mut Workspace) -> R) -> R {
    WORKSPACE.with(|w| f(&mut w.borrow_mut()))
}

/// Runs `f(k0, a, b0, m)` on the segments of entries `off..off + len` of a
/// lattice whose rows hold `nb` entries: `m` (at most [`SEGMENT`]) entries of
/// row `a` from column `b0`, flat index `k0`. Segments never straddle rows.
pub(super) fn each_segment(
    nb: usize,
    off: usize,
    len: usize,
    mut f: impl FnMut(usize, usize, usize, usize),
) {
    let end = off + len;
    let mut k = off;
    while k < end {
        let (a, b) = (k / nb, k % nb);
        let m = SEGMENT.min(nb - b).min(end - k);
        f(k, a, b, m);
        k += m;
    }
}

/// A velocity sampler's stencils at the entries of a lattice whose corners
/// are all plain values (a periodic box): per row, the two rows' offsets
/// into the sampled array and the weights along x; per column, the two
/// columns and the weights along y.
pub(super) struct PlainTable {
    rows: Vec<([usize; 2], [f64; 2])>,
    cols: Vec<([usize; 2], [f64; 2])>,
    /// From each column, how many columns read consecutive entries (the
    /// corners of column `b + t` are those of `b` shifted by `t`): there the
    /// loads are slices, not gathers.
    runs: Vec<usize>,
}

impl PlainTable {
    /// The flat form of `t`, or `None` if some stencil reads a ghost.
    pub(super) fn of(t: &LatticeStencils) -> Option<Self> {
        if !t.along_x.iter().chain(&t.along_y).all(|h| h.inside) {
            return None;
        }
        let cols: Vec<_> = t
            .along_y
            .iter()
            .map(|h| (h.idx, Stencil::weights(h)))
            .collect();
        let mut runs = vec![1; cols.len()];
        for b in (0..cols.len().saturating_sub(1)).rev() {
            let ([j0, j1], [n0, n1]) = (cols[b].0, cols[b + 1].0);
            if n0 == j0 + 1 && n1 == j1 + 1 {
                runs[b] = runs[b + 1] + 1;
            }
        }
        Some(PlainTable {
            rows: t
                .along_x
                .iter()
                .map(|h| ([h.idx[0] * t.nb, h.idx[1] * t.nb], Stencil::weights(h)))
                .collect(),
            cols,
            runs,
        })
    }

    /// [`LatticeStencils::value_at`] of `u` at the entries `(a, b0 + l)`,
    /// into `out[l]` for every `l` of `out`.
    #[inline(always)]
    fn values(&self, a: usize, b0: usize, u: &[f64], out: &mut [f64], work: &mut Corners) {
        let m = out.len();
        let ([r0, r1], wx) = self.rows[a];
        let Corners { c, wy } = work;
        let cols = &self.cols[b0..b0 + m];
        if self.runs[b0] >= m {
            // the same entries as the loads below, taken as slices
            let [j0, j1] = cols[0].0;
            for (r, row) in [r0, r1].into_iter().zip(c.iter_mut()) {
                row[0][..m].copy_from_slice(&u[r + j0..r + j0 + m]);
                row[1][..m].copy_from_slice(&u[r + j1..r + j1 + m]);
            }
        } else {
            for (l, &([j0, j1], _)) in cols.iter().enumerate() {
                c[0][0][l] = u[r0 + j0];
                c[0][1][l] = u[r0 + j1];
                c[1][0][l] = u[r1 + j0];
                c[1][1][l] = u[r1 + j1];
            }
        }
        for (l, &(_, w)) in cols.iter().enumerate() {
            wy[0][l] = w[0];
            wy[1][l] = w[1];
        }
        let [[c00, c01], [c10, c11]] = &*c;
        let (c00, c01, c10, c11) = (&c00[..m], &c01[..m], &c10[..m], &c11[..m]);
        let (wy0, wy1) = (&wy[0][..m], &wy[1][..m]);
        // `bilinear`, term for term
        for l in 0..m {
            out[l] = wx[0] * (wy0[l] * c00[l] + wy1[l] * c01[l])
                + wx[1] * (wy0[l] * c10[l] + wy1[l] * c11[l]);
        }
    }
}

/// Room for the corner values and the weights along y of a segment's
/// velocity interpolation.
pub(super) struct Corners {
    c: [[Segment; 2]; 2],
    wy: [Segment; 2],
}

impl Default for Corners {
    fn default() -> Self {
        Corners {
            c: [[[0.0; SEGMENT]; 2]; 2],
            wy: [[0.0; SEGMENT]; 2],
        }
    }
}

/// The tracing velocity of a periodic field's entries by segments: the
/// component living on the field's lattice read, the others interpolated
/// (as [`Tracer::velocity_at`]).
pub(super) struct SegmentVelocity<'a> {
    lattice: Lattice,
    ux: &'a [f64],
    uy: &'a [f64],
    tx: PlainTable,
    ty: PlainTable,
}

impl<'a> SegmentVelocity<'a> {
    /// The segment form of `tr`'s velocity at the entries of `lattice` on a
    /// periodic box.
    ///
    /// # Panics
    /// If a stencil reads a ghost: never on a box periodic along both axes
    /// (every axis wraps), the only place a field's sampler is
    /// [`super::sampling::Sampler::periodic`].
    pub(super) fn periodic(tr: &Tracer<'a>, lattice: Lattice) -> Self {
        let [tx, ty] = tr.tables(lattice);
        let plain = |t| PlainTable::of(t).expect("a periodic box's stencils read no ghost");
        SegmentVelocity {
            lattice,
            ux: tr.ux,
            uy: tr.uy,
            tx: plain(&tx),
            ty: plain(&ty),
        }
    }

    /// The velocity at the `m` entries from `k0` (flat), row `a`, column
    /// `b0`, into the first `m` entries of `v`.
    #[inline(always)]
    pub(super) fn at(
        &self,
        a: usize,
        k0: usize,
        b0: usize,
        m: usize,
        v: &mut [Segment; 2],
        work: &mut Corners,
    ) {
        let [vx, vy] = v;
        let (vx, vy) = (&mut vx[..m], &mut vy[..m]);
        let own = |u: &[f64], out: &mut [f64]| out.copy_from_slice(&u[k0..k0 + m]);
        match self.lattice {
            Lattice::FaceX => {
                own(self.ux, vx);
                self.ty.values(a, b0, self.uy, vy, work);
            }
            Lattice::FaceY => {
                self.tx.values(a, b0, self.ux, vx, work);
                own(self.uy, vy);
            }
            Lattice::Cell => {
                self.tx.values(a, b0, self.ux, vx, work);
                self.ty.values(a, b0, self.uy, vy, work);
            }
        }
    }
}

/// The corner values of the departure points of a segment and the fractions
/// of the way along x and y: [`Periodic::locate`] and
/// [`super::sampling::corner_values`] entry by entry. A workspace, filled
/// by [`Departures::locate`] segment after segment (a [`Workspace`]'s).
pub(super) struct Departures {
    m: usize,
    /// The corner indices `k` hold the corners (one wrap sufficed).
    indexed: bool,
    corners: [[Segment; 2]; 2],
    fx: Segment,
    fy: Segment,
    s: [Segment; 2],
    cell: [Segment<i32>; 2],
    k: [[Segment<i32>; 2]; 2],
}

impl Default for Departures {
    fn default() -> Self {
        Departures {
            m: 0,
            indexed: false,
            corners: [[[0.0; SEGMENT]; 2]; 2],
            fx: [0.0; SEGMENT],
            fy: [0.0; SEGMENT],
            s: [[0.0; SEGMENT]; 2],
            cell: [[0; SEGMENT]; 2],
            k: [[[0; SEGMENT]; 2]; 2],
        }
    }
}

impl Departures {
    /// The departure points `(x − dt v_x[l], ys[l] − dt v_y[l])` on the
    /// lattice of `lean`, with the values of `q` at their corners.
    #[inline(always)]
    pub(super) fn locate(
        &mut self,
        lean: &Periodic,
        q: &[f64],
        x: f64,
        ys: &[f64],
        v: &[Segment; 2],
        dt: f64,
    ) {
        let m = ys.len();
        self.m = m;
        let (vx, vy) = (&v[0][..m], &v[1][..m]);
        let [sx, sy] = &mut self.s;
        let (sx, sy) = (&mut sx[..m], &mut sy[..m]);
        for l in 0..m {
            // a division, not a product with 1/h, as in `Periodic::locate`
            sx[l] = (x - dt * vx[l]) / lean.h.0 - lean.offsets.0;
            sy[l] = (ys[l] - dt * vy[l]) / lean.h.1 - lean.offsets.1;
        }
        let [ci, cj] = &mut self.cell;
        // indices in i32 arithmetic (vector lanes on AVX2 too) where they fit
        let fits = i32::try_from(q.len()).is_ok();
        let one_wrap = fits
            & floors(sx, lean.n[0], &mut self.fx[..m], &mut ci[..m])
            & floors(sy, lean.n[1], &mut self.fy[..m], &mut cj[..m]);
        self.indexed = one_wrap;
        if one_wrap {
            let (na, nb) = (lean.n[0] as i32, lean.n[1] as i32);
            let (ci, cj) = (&ci[..m], &cj[..m]);
            let [[k00, k01], [k10, k11]] = &mut self.k;
            let (k00, k01) = (&mut k00[..m], &mut k01[..m]);
            let (k10, k11) = (&mut k10[..m], &mut k11[..m]);
            for l in 0..m {
                let (i0, j0) = (ci[l], cj[l]);
                let i1 = if i0 + 1 == na { 0 } else { i0 + 1 };
                let j1 = if j0 + 1 == nb { 0 } else { j0 + 1 };
                let (r0, r1) = (i0 * nb, i1 * nb);
                k00[l] = r0 + j0;
                k01[l] = r0 + j1;
                k10[l] = r1 + j0;
                k11[l] = r1 + j1;
            }
            self.load(q);
        } else {
            // a departure more than a box away, or not a number: `wrap`
            let nb = lean.n[1];
            for l in 0..m {
                let (i0, i1, _) = wrap(sx[l], lean.n[0]);
                let (j0, j1, _) = wrap(sy[l], nb);
                let (r0, r1) = (&q[i0 * nb..], &q[i1 * nb..]);
                self.corners[0][0][l] = r0[j0];
                self.corners[0][1][l] = r0[j1];
                self.corners[1][0][l] = r1[j0];
                self.corners[1][1][l] = r1[j1];
            }
        }
    }

    /// The values of `q` at the corner indices.
    #[inline(always)]
    fn load(&mut self, q: &[f64]) {
        for a in 0..2 {
            for b in 0..2 {
                let (c, k) = (&mut self.corners[a][b][..self.m], &self.k[a][b][..self.m]);
                for l in 0..c.len() {
                    c[l] = q[k[l] as usize];
                }
            }
        }
    }

    /// The bilinear values at the departure points, into `out`.
    #[inline(always)]
    pub(super) fn values(&self, out: &mut Segment) {
        let m = self.m;
        let [[c00, c01], [c10, c11]] = &self.corners;
        let (c00, c01, c10, c11) = (&c00[..m], &c01[..m], &c10[..m], &c11[..m]);
        let (fx, fy, out) = (&self.fx[..m], &self.fy[..m], &mut out[..m]);
        // `bilinear` with the weights `[1 − f, f]`, term for term
        for l in 0..m {
            let (wx, wy) = ([1.0 - fx[l], fx[l]], [1.0 - fy[l], fy[l]]);
            out[l] = wx[0] * (wy[0] * c00[l] + wy[1] * c01[l])
                + wx[1] * (wy[0] * c10[l] + wy[1] * c11[l]);
        }
    }

    /// The smallest and largest corner value of each departure point (the
    /// limiter's range, as [`super::sampling::bilinear_and_range`]).
    #[inline(always)]
    pub(super) fn ranges(&self, lo: &mut Segment, hi: &mut Segment) {
        let m = self.m;
        let [[c00, c01], [c10, c11]] = &self.corners;
        let (c00, c01, c10, c11) = (&c00[..m], &c01[..m], &c10[..m], &c11[..m]);
        let (lo, hi) = (&mut lo[..m], &mut hi[..m]);
        for l in 0..m {
            lo[l] = c00[l].min(c01[l]).min(c10[l]).min(c11[l]);
            hi[l] = c00[l].max(c01[l]).max(c10[l]).max(c11[l]);
        }
    }
}

impl Departures {
    /// Whether [`Departures::scatter`] may be used: the corners' indices
    /// were computed (else the segment's departures need the scalar path).
    #[inline(always)]
    pub(super) fn indexed(&self) -> bool {
        self.indexed
    }

    /// The slopes of the bilinear interpolant along x and y at the
    /// departure points, in lattice units, into `sx`, `sy`
    /// ([`super::sampling::bilinear_slopes`], term for term).
    #[inline(always)]
    pub(super) fn slopes(&self, sx: &mut Segment, sy: &mut Segment) {
        let m = self.m;
        let [[c00, c01], [c10, c11]] = &self.corners;
        let (c00, c01, c10, c11) = (&c00[..m], &c01[..m], &c10[..m], &c11[..m]);
        let (fx, fy) = (&self.fx[..m], &self.fy[..m]);
        let (sx, sy) = (&mut sx[..m], &mut sy[..m]);
        for l in 0..m {
            let (wx, wy) = ([1.0 - fx[l], fx[l]], [1.0 - fy[l], fy[l]]);
            sx[l] = wy[0] * (c10[l] - c00[l]) + wy[1] * (c11[l] - c01[l]);
            sy[l] = wx[0] * (c01[l] - c00[l]) + wx[1] * (c11[l] - c10[l]);
        }
    }

    /// Adds `c · wx[a] · wy[b]` to the corner `[a][b]` of the departure
    /// point of entry `l` in `grad` (the transpose of
    /// [`Departures::values`]; [`super::sampling::bilinear_scatter`], term
    /// for term and in its order). Only where [`Departures::indexed`].
    #[inline(always)]
    pub(super) fn scatter(&self, l: usize, c: f64, grad: &mut [f64]) {
        debug_assert!(self.indexed && l < self.m);
        let (wx, wy) = (
            [1.0 - self.fx[l], self.fx[l]],
            [1.0 - self.fy[l], self.fy[l]],
        );
        for (ka, wa) in self.k.iter().zip(wx) {
            for (kab, wb) in ka.iter().zip(wy) {
                grad[kab[l] as usize] += c * wa * wb;
            }
        }
    }
}

/// The floors of `s` wrapped once onto `0..n` (into `cell`) and the
/// fractions `s − ⌊s⌋` (into `frac`), as [`wrap`] computes them; false if
/// some floor needs more than one wrap (or is not a number), where `cell`
/// is unspecified.
#[inline(always)]
fn floors(s: &[f64], n: usize, frac: &mut [f64], cell: &mut [i32]) -> bool {
    let nf = n as f64;
    let mut one_wrap = true;
    for l in 0..s.len().min(frac.len()).min(cell.len()) {
        let fl = s[l].floor();
        frac[l] = s[l] - fl;
        // `wrap`'s single wrap in floating point: exact on whole numbers,
        // so the same index wherever one wrap suffices
        let w = if fl < 0.0 {
            fl + nf
        } else if fl >= nf {
            fl - nf
        } else {
            fl
        };
        one_wrap &= (w >= 0.0) & (w < nf);
        cell[l] = small_whole(w);
    }
    one_wrap
}

/// `w` as an integer, for a whole `w` in `[0, 2³¹)`: the low bits of
/// `w + 2⁵²`, whose unit in the last place is 1 (exact, and unlike `as`,
/// which must saturate, it vectorises).
#[inline(always)]
fn small_whole(w: f64) -> i32 {
    (w + 4_503_599_627_370_496.0).to_bits() as u32 as i32
}

impl Tracer<'_> {
    /// A semi-Lagrangian step on a periodic box (`lean`, the field's
    /// sampler) by segments: each entry's tracing velocity computed where it
    /// is used, not stored. The arithmetic of [`Tracer::velocities`] and
    /// [`Tracer::semi_lagrangian`], so the same bits.
    pub(super) fn periodic_step(
        &self,
        field: &Field<'_>,
        lean: Periodic,
        q: &[f64],
        dt: f64,
    ) -> Vec<f64> {
        let vel = SegmentVelocity::periodic(self, field.lattice);
        let [xs, ys] = &field.position;
        // every entry is written
        let mut out = crate::buffers::scratch(q.len());
        super::tracer::for_blocks(&mut out, |off, block| {
            with_workspace(|w| {
                let Workspace {
                    departures: dep,
                    corners,
                    v,
                    out: [value, ..],
                } = w;
                each_segment(field.sampler.nb, off, block.len(), |k0, a, b0, m| {
                    vel.at(a, k0, b0, m, v, corners);
                    dep.locate(&lean, q, xs[a], &ys[b0..b0 + m], v, dt);
                    dep.values(value);
                    for (l, &val) in value[..m].iter().enumerate() {
                        let k = k0 + l;
                        block[k - off] = if field.free(k) { val } else { q[k] };
                    }
                });
            });
        });
        out
    }
}
