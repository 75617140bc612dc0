//! The transfers between a level and the next coarser one, one axis at a
//! time: bilinear prolongation `P` between cell centres (with the wall's
//! ghost rule) and restriction `R = ¼ Pᵀ`, fused with the residual. Both
//! run on all cores for large levels, with the serial order of every sum.

use diffphys_tape::parallel;
use rayon::prelude::*;

use super::block_cells;
use super::hierarchy::Level;
use crate::Boundary;

/// Rows of `n` cells per block of a parallel transfer (see [`block_cells`]).
fn block_rows(n: usize) -> usize {
    block_cells().div_ceil(n).max(1)
}

/// `blocks` scratch lanes of `len` entries each, carved from `lanes` (grown
/// once if it is short: the cycle's workspace keeps it between applications).
fn lanes_of(lanes: &mut Vec<f64>, blocks: usize, len: usize) -> &mut [f64] {
    let need = blocks * len.max(1);
    if lanes.len() < need {
        lanes.resize(need, 0.0);
    }
    &mut lanes[..need]
}

/// The sign a wall's ghost cell carries in the interpolation: `−1` Dirichlet,
/// `+1` closed.
fn ghost_sign(b: Boundary) -> f64 {
    match b {
        Boundary::ZeroDirichlet => -1.0,
        _ => 1.0,
    }
}

/// One axis of the transfer between a level and the next coarser one: for
/// each fine index, its parent (weight 3/4) and the other coarse cell of its
/// interpolation with that cell's weight (`±1/4` at the parent itself across
/// a wall).
#[derive(Debug, Clone)]
pub(super) struct Transfer1 {
    pub(super) coarse: usize,
    pub(super) rows: Vec<(usize, usize, f64)>,
    /// The coarse indices outside the regular middle, each with the fine
    /// indices and weights that `Pᵀ` gathers into it.
    pub(super) edges: Vec<(usize, Vec<(usize, f64)>)>,
}

impl Transfer1 {
    pub(super) fn new(n: usize, b: Boundary) -> Self {
        let coarse = n.div_ceil(2);
        let rows = (0..n)
            .map(|f| {
                let parent = f / 2;
                let side = if f % 2 == 0 {
                    parent as isize - 1
                } else {
                    parent as isize + 1
                };
                if (0..coarse as isize).contains(&side) {
                    (parent, side as usize, 0.25)
                } else if b == Boundary::Periodic {
                    (parent, side.rem_euclid(coarse as isize) as usize, 0.25)
                } else {
                    (parent, parent, 0.25 * ghost_sign(b))
                }
            })
            .collect::<Vec<_>>();
        let mut edges: Vec<(usize, Vec<(usize, f64)>)> = (0..coarse)
            .filter(|&c| !Self::regular(c, n))
            .map(|c| (c, Vec::new()))
            .collect();
        for (f, &(p, s, w)) in rows.iter().enumerate() {
            for (c, weight) in [(p, 0.75), (s, w)] {
                if let Some((_, list)) = edges.iter_mut().find(|(e, _)| *e == c) {
                    list.push((f, weight));
                }
            }
        }
        Transfer1 {
            coarse,
            rows,
            edges,
        }
    }

    /// Whether coarse index `c` gathers exactly fine `2c − 1 … 2c + 2` with
    /// weights `¼, ¾, ¾, ¼` (no wall, no wrap-around).
    fn regular(c: usize, n: usize) -> bool {
        c >= 1 && 2 * c + 2 < n
    }

    /// `coarse = P₁ᵀ fine` along this axis.
    fn restrict(&self, fine: &[f64], coarse: &mut [f64]) {
        let n = fine.len();
        let coarse = &mut coarse[..self.coarse];
        for c in 1..self.coarse {
            if !Self::regular(c, n) {
                break;
            }
            coarse[c] =
                0.75 * (fine[2 * c] + fine[2 * c + 1]) + 0.25 * (fine[2 * c - 1] + fine[2 * c + 2]);
        }
        for (c, list) in &self.edges {
            coarse[*c] = list.iter().map(|&(f, w)| w * fine[f]).sum();
        }
    }

    /// `fine += P₁ coarse` along this axis, on the cells `active` allows.
    fn prolong_add(&self, coarse: &[f64], fine: &mut [f64], active: Option<&[bool]>) {
        let n = fine.len();
        let interp = |f: usize| {
            let (p, s, w) = self.rows[f];
            0.75 * coarse[p] + w * coarse[s]
        };
        if let Some(active) = active {
            for f in 0..n {
                if active[f] {
                    fine[f] += interp(f);
                }
            }
            return;
        }
        // Fine 2c and 2c + 1 for 1 ≤ c < coarse − 1 are regular.
        let hi = 2 * self.coarse.saturating_sub(1);
        for f in (0..n.min(2)).chain(hi.max(2)..n) {
            fine[f] += interp(f);
        }
        for c in 1..self.coarse.saturating_sub(1) {
            fine[2 * c] += 0.75 * coarse[c] + 0.25 * coarse[c - 1];
            fine[2 * c + 1] += 0.75 * coarse[c] + 0.25 * coarse[c + 1];
        }
    }
}

impl Level {
    /// The residual `b − A x` of row `i` into `out` (length `ny`), inactive
    /// cells 0 (`P` has zero rows there).
    fn residual_row(&self, x: &[f64], b: &[f64], i: usize, out: &mut [f64]) {
        let ny = self.ny;
        let base = i * ny;
        let general = |j: usize| {
            let k = base + j;
            if self.is_active(k) {
                b[k] - (self.diag[k] * x[k] - self.off(x, i, j))
            } else {
                0.0
            }
        };
        match self.uniform {
            Some((ax, ay, inv_d)) if i > 0 && i + 1 < self.nx && ny > 2 => {
                let d = 1.0 / inv_d;
                let (up, row, down) = (
                    &x[base - ny..base],
                    &x[base..base + ny],
                    &x[base + ny..base + 2 * ny],
                );
                let brow = &b[base..base + ny];
                out[0] = general(0);
                for j in 1..ny - 1 {
                    let off = ax * (up[j] + down[j]) + ay * (row[j - 1] + row[j + 1]);
                    out[j] = brow[j] - (d * row[j] - off);
                }
                out[ny - 1] = general(ny - 1);
            }
            _ => {
                for (j, o) in out.iter_mut().enumerate().take(ny) {
                    *o = general(j);
                }
            }
        }
    }

    /// `coarse = R (b − A x) = ¼ Pᵀ (b − A x)`, row by row: each coarse row
    /// adds its fine rows' restricted residuals in ascending fine order (`row`
    /// of length `ny` and `tmp` of the coarse row length are scratch). On all
    /// cores for a large coarse level, in blocks of coarse rows (a fine row
    /// next to two blocks is computed by both), with the serial sums' order,
    /// so the same result; `lanes` holds each block's two rows.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn restrict_residual(
        &self,
        x: &[f64],
        b: &[f64],
        (tx, ty): (&Transfer1, &Transfer1),
        coarse: &mut [f64],
        row: &mut [f64],
        tmp: &mut [f64],
        lanes: &mut Vec<f64>,
    ) {
        let cny = ty.coarse;
        if cny == 0 {
            return;
        }
        if !parallel::is_parallel(coarse.len()) {
            self.restrict_block(x, b, (tx, ty), 0, coarse, row, tmp);
            return;
        }
        let rows = block_rows(cny);
        let len = self.ny + cny;
        let blocks = coarse.len().div_ceil(rows * cny);
        coarse
            .par_chunks_mut(rows * cny)
            .zip(lanes_of(lanes, blocks, len).par_chunks_mut(len))
            .enumerate()
            .for_each(|(k, (block, lane))| {
                let (row, tmp) = lane.split_at_mut(self.ny);
                self.restrict_block(x, b, (tx, ty), k * rows, block, row, tmp);
            });
    }

    /// [`Level::restrict_residual`] into the coarse rows from `c0` on that
    /// `block` holds.
    #[allow(clippy::too_many_arguments)]
    fn restrict_block(
        &self,
        x: &[f64],
        b: &[f64],
        (tx, ty): (&Transfer1, &Transfer1),
        c0: usize,
        block: &mut [f64],
        row: &mut [f64],
        tmp: &mut [f64],
    ) {
        let cny = ty.coarse;
        let c1 = c0 + block.len() / cny;
        let into = |c: usize| (c0..c1).contains(&c);
        block.fill(0.0);
        for (i, &(p, s, w)) in tx.rows.iter().enumerate() {
            if !into(p) && !into(s) {
                continue;
            }
            self.residual_row(x, b, i, row);
            ty.restrict(&row[..self.ny], tmp);
            for (c, weight) in [(p, 0.25 * 0.75), (s, 0.25 * w)] {
                if into(c) {
                    let out = &mut block[(c - c0) * cny..(c - c0 + 1) * cny];
                    for (o, &t) in out.iter_mut().zip(&tmp[..cny]) {
                        *o += weight * t;
                    }
                }
            }
        }
    }

    /// `x += P coarse`, row by row (`tmp` of the coarse row length is
    /// scratch); on all cores for a large level, each block's row in `lanes`.
    pub(super) fn prolong_add(
        &self,
        coarse: &[f64],
        (tx, ty): (&Transfer1, &Transfer1),
        x: &mut [f64],
        tmp: &mut [f64],
        lanes: &mut Vec<f64>,
    ) {
        let ny = self.ny;
        if ny == 0 {
            return;
        }
        if !parallel::is_parallel(x.len()) {
            self.prolong_block(coarse, (tx, ty), 0, x, tmp);
            return;
        }
        let rows = block_rows(ny);
        let len = ty.coarse;
        let blocks = x.len().div_ceil(rows * ny);
        x.par_chunks_mut(rows * ny)
            .zip(lanes_of(lanes, blocks, len).par_chunks_mut(len.max(1)))
            .enumerate()
            .for_each(|(k, (block, tmp))| {
                self.prolong_block(coarse, (tx, ty), k * rows, block, tmp);
            });
    }

    /// [`Level::prolong_add`] on the fine rows from `i0` on that `block` holds.
    fn prolong_block(
        &self,
        coarse: &[f64],
        (tx, ty): (&Transfer1, &Transfer1),
        i0: usize,
        block: &mut [f64],
        tmp: &mut [f64],
    ) {
        let (ny, cny) = (self.ny, ty.coarse);
        for (r, xrow) in block.chunks_exact_mut(ny).enumerate() {
            let i = i0 + r;
            let (p, s, w) = tx.rows[i];
            let (cp, cs) = (
                &coarse[p * cny..(p + 1) * cny],
                &coarse[s * cny..(s + 1) * cny],
            );
            for ((t, &a), &c) in tmp[..cny].iter_mut().zip(cp).zip(cs) {
                *t = 0.75 * a + w * c;
            }
            let active = self.active.as_ref().map(|a| &a[i * ny..(i + 1) * ny]);
            ty.prolong_add(&tmp[..cny], xrow, active);
        }
    }
}
