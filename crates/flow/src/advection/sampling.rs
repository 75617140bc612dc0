//! Bilinear interpolation on one lattice of the staggered grid with the side
//! conditions: the stencils a departure point reads (values, slopes and the
//! transposed scatter), per axis and per lattice.

use crate::grid::{FlowGrid, Lattice};
use crate::sides::{Ghost, Side};

/// How one axis of a lattice continues beyond its last entries.
#[derive(Debug, Clone, Copy)]
pub(super) enum AxisRule {
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
pub(super) struct Hit {
    pub(super) idx: [usize; 2],
    pub(super) factor: [f64; 2],
    pub(super) wall: [f64; 2],
    pub(super) side: [usize; 2],
    pub(super) frac: f64,
    /// Whether the sample moves with the coordinate (false where clamped).
    pub(super) moves: bool,
    /// Whether both entries are plain lattice values (factor 1, no wall term).
    pub(super) inside: bool,
}

impl AxisRule {
    #[inline(always)]
    pub(super) fn hit(self, s: f64) -> Hit {
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
pub(super) fn wrap(s: f64, n: usize) -> (usize, usize, f64) {
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
pub(super) fn bilinear(v: [[f64; 2]; 2], wx: [f64; 2], wy: [f64; 2]) -> f64 {
    wx[0] * (wy[0] * v[0][0] + wy[1] * v[0][1]) + wx[1] * (wy[0] * v[1][0] + wy[1] * v[1][1])
}

/// [`bilinear`] and the smallest and largest of the corner values `v` (the
/// MacCormack limiter's range).
#[inline(always)]
pub(super) fn bilinear_and_range(v: [[f64; 2]; 2], wx: [f64; 2], wy: [f64; 2]) -> (f64, [f64; 2]) {
    let value = bilinear(v, wx, wy);
    let lo = v[0][0].min(v[0][1]).min(v[1][0]).min(v[1][1]);
    let hi = v[0][0].max(v[0][1]).max(v[1][0]).max(v[1][1]);
    (value, [lo, hi])
}

/// `∂ bilinear / ∂s` along x and along y, in lattice units.
#[inline(always)]
pub(super) fn bilinear_slopes(v: [[f64; 2]; 2], wx: [f64; 2], wy: [f64; 2]) -> (f64, f64) {
    (
        wy[0] * (v[1][0] - v[0][0]) + wy[1] * (v[1][1] - v[0][1]),
        wx[0] * (v[0][1] - v[0][0]) + wx[1] * (v[1][1] - v[1][0]),
    )
}

/// The values of `u` at the plain lattice entries `k`.
#[inline(always)]
pub(super) fn corner_values(u: &[f64], k: [[usize; 2]; 2]) -> [[f64; 2]; 2] {
    [[u[k[0][0]], u[k[0][1]]], [u[k[1][0]], u[k[1][1]]]]
}

/// Adds `c · wx[a] · wy[b]` to the plain lattice entry `k[a][b]` (the
/// transpose of [`bilinear`]), corners in the order `Stencil::scatter` takes.
#[inline(always)]
pub(super) fn bilinear_scatter(
    k: [[usize; 2]; 2],
    wx: [f64; 2],
    wy: [f64; 2],
    c: f64,
    grad: &mut [f64],
) {
    for (ka, wa) in k.iter().zip(wx) {
        for (&kab, wb) in ka.iter().zip(wy) {
            grad[kab] += c * wa * wb;
        }
    }
}

/// Four plain lattice entries `[[k00, k01], [k10, k11]]` and the bilinear
/// weights along x and y.
pub(super) type PlainCorners = ([[usize; 2]; 2], [f64; 2], [f64; 2]);

/// A sampler both of whose axes wrap (a periodic box): every corner is a
/// plain lattice value, so a departure point needs only its two brackets per
/// axis. The arithmetic is [`Sampler::locate`]'s and [`Stencil`]'s, term for
/// term, so the same bits.
#[derive(Debug, Clone, Copy)]
pub(super) struct Periodic {
    pub(super) n: [usize; 2],
    pub(super) h: (f64, f64),
    pub(super) offsets: (f64, f64),
}

impl Periodic {
    /// The corners' indices `[[k00, k01], [k10, k11]]` and the weights along
    /// x and y of the point `p`.
    #[inline(always)]
    pub(super) fn locate(&self, p: [f64; 2]) -> PlainCorners {
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
pub(super) struct Sampler {
    pub(super) rx: AxisRule,
    pub(super) ry: AxisRule,
    pub(super) offsets: (f64, f64),
    pub(super) h: (f64, f64),
    pub(super) nb: usize,
}

/// Where a sample reads: the corners along x and y.
#[derive(Debug, Clone, Copy)]
pub(super) struct Stencil {
    pub(super) hx: Hit,
    pub(super) hy: Hit,
    pub(super) nb: usize,
    /// Every corner is a plain lattice value (the common case, away from
    /// the walls): `corner` is a load and `scatter_corner` one add.
    pub(super) inside: bool,
}

impl Sampler {
    pub(super) fn new(grid: &FlowGrid, lattice: Lattice) -> Self {
        let sides = &grid.sides;
        let ghost = |lo: Side, hi: Side, n: usize| {
            let Ghost {
                factor: fl,
                wall: wl,
            } = sides.get(lo).ghost(grid.normal_size(lo));
            let Ghost {
                factor: fh,
                wall: wh,
            } = sides.get(hi).ghost(grid.normal_size(hi));
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
    pub(super) fn periodic(&self) -> Option<Periodic> {
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
    pub(super) fn locate(&self, p: [f64; 2]) -> Stencil {
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
pub(super) struct LatticeStencils {
    pub(super) along_x: Vec<Hit>,
    pub(super) along_y: Vec<Hit>,
    pub(super) nb: usize,
}

impl LatticeStencils {
    /// The plain lattice entries and the weights of entry `(a, b)`'s
    /// stencil where all four corners are plain values (no ghost, no wall).
    #[inline(always)]
    pub(super) fn plain(&self, [a, b]: [usize; 2]) -> Option<PlainCorners> {
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
    pub(super) fn value_at(&self, ab: [usize; 2], u: &[f64], walls: &[f64; 4]) -> f64 {
        match self.plain(ab) {
            Some((k, wx, wy)) => bilinear(corner_values(u, k), wx, wy),
            None => self.at(ab).value(u, walls),
        }
    }

    /// `at(ab).scatter(c, grad_u, grad_walls)`, without building the stencil
    /// where its corners are plain (the same arithmetic, so the same bits).
    #[inline(always)]
    pub(super) fn scatter_at(
        &self,
        ab: [usize; 2],
        c: f64,
        grad_u: &mut [f64],
        grad_walls: &mut [f64; 4],
    ) {
        match self.plain(ab) {
            Some((k, wx, wy)) => bilinear_scatter(k, wx, wy, c, grad_u),
            None => self.at(ab).scatter(c, grad_u, grad_walls),
        }
    }

    /// The stencil of entry `(a, b)`: the one `locate` gives at its position.
    #[inline(always)]
    pub(super) fn at(&self, [a, b]: [usize; 2]) -> Stencil {
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
    pub(super) fn on_lattice(&self, grid: &FlowGrid, lattice: Lattice) -> LatticeStencils {
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
    pub(super) fn weights(h: &Hit) -> [f64; 2] {
        [1.0 - h.frac, h.frac]
    }

    /// The corner value `(a, b)` with its ghost factors.
    #[inline(always)]
    pub(super) fn corner(&self, a: usize, b: usize, u: &[f64], walls: &[f64; 4]) -> f64 {
        let k = self.hx.idx[a] * self.nb + self.hy.idx[b];
        if self.inside {
            return u[k];
        }
        self.hx.factor[a] * self.hy.factor[b] * u[k]
            + self.hx.wall[a] * walls[self.hx.side[a]]
            + self.hy.wall[b] * walls[self.hy.side[b]]
    }

    #[inline(always)]
    pub(super) fn corners(&self, u: &[f64], walls: &[f64; 4]) -> [[f64; 2]; 2] {
        [
            [self.corner(0, 0, u, walls), self.corner(0, 1, u, walls)],
            [self.corner(1, 0, u, walls), self.corner(1, 1, u, walls)],
        ]
    }

    /// The interpolated value.
    #[inline(always)]
    pub(super) fn value(&self, u: &[f64], walls: &[f64; 4]) -> f64 {
        let (wx, wy) = (Self::weights(&self.hx), Self::weights(&self.hy));
        bilinear(self.corners(u, walls), wx, wy)
    }

    /// `∂value/∂s` along x and y in lattice units (zero where clamped).
    #[inline(always)]
    pub(super) fn slopes(&self, u: &[f64], walls: &[f64; 4]) -> (f64, f64) {
        let (wx, wy) = (Self::weights(&self.hx), Self::weights(&self.hy));
        let (sx, sy) = bilinear_slopes(self.corners(u, walls), wx, wy);
        (
            if self.hx.moves { sx } else { 0.0 },
            if self.hy.moves { sy } else { 0.0 },
        )
    }

    /// Adds `c · ∂value/∂u` to `grad_u` and `c · ∂value/∂U` to `grad_walls`.
    #[inline(always)]
    pub(super) fn scatter(&self, c: f64, grad_u: &mut [f64], grad_walls: &mut [f64; 4]) {
        let (wx, wy) = (Self::weights(&self.hx), Self::weights(&self.hy));
        for (a, wa) in wx.iter().enumerate() {
            for (b, wb) in wy.iter().enumerate() {
                self.scatter_corner(a, b, c * wa * wb, grad_u, grad_walls);
            }
        }
    }

    #[inline(always)]
    pub(super) fn scatter_corner(
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
    pub(super) fn value_and_range(&self, u: &[f64], walls: &[f64; 4]) -> (f64, [f64; 2]) {
        let (wx, wy) = (Self::weights(&self.hx), Self::weights(&self.hy));
        bilinear_and_range(self.corners(u, walls), wx, wy)
    }

    /// The corner holding the smallest and the largest value.
    #[inline(always)]
    pub(super) fn extremes(
        &self,
        u: &[f64],
        walls: &[f64; 4],
    ) -> ((usize, usize, f64), (usize, usize, f64)) {
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
