//! The smoother: Gauss–Seidel in red–black order, rows and colours
//! interleaved (red on row `i`, then black on row `i − 1`: one pass over
//! memory per sweep), forward before the coarse correction and in exactly
//! the reverse order after it, which keeps the cycle symmetric.
//!
//! On a large level the sweep runs on all cores, in blocks of rows, with the
//! same result to the bit: a red cell's update reads only black neighbours
//! and a black cell's only red ones, so any order that updates every red
//! cell from the old black values and then every black cell from the new red
//! ones gives the same numbers (in reverse: every black cell from the old red
//! values, then every red one). Each block interleaves its own rows and
//! leaves the black cells of its first and last row (whose neighbours
//! another block updates) to a phase of their own, after all blocks going
//! forward and before them in reverse; the serial sweep is the same with one
//! block. (A periodic x-axis of odd
//! length breaks the checkerboard across rows, so such a level runs as one
//! block.)

use diffphys_tape::parallel;
use rayon::prelude::*;

use super::block_cells;
use super::hierarchy::Level;
use crate::Boundary;

/// A level's iterate shared by the blocks of a parallel sweep, read and
/// written element by element through the raw pointer (never as a slice, so
/// that no block holds a reference to cells another block writes).
#[derive(Clone, Copy)]
struct Cells(*mut f64);

// SAFETY: the blocks of one phase of a sweep write disjoint cells, and no
// cell that one block writes is read by another in the same phase (see
// `Level::sweep_blocks`); the phases are separated by the join of rayon's
// parallel iterator.
unsafe impl Send for Cells {}
unsafe impl Sync for Cells {}

impl Cells {
    /// # Safety
    /// `k` is in bounds and no other thread writes cell `k` now.
    #[inline(always)]
    unsafe fn get(self, k: usize) -> f64 {
        unsafe { *self.0.add(k) }
    }

    /// # Safety
    /// `k` is in bounds and no other thread reads or writes cell `k` now.
    #[inline(always)]
    unsafe fn set(self, k: usize, v: f64) {
        unsafe { *self.0.add(k) = v }
    }
}

/// Rows per block of a parallel sweep, at least.
const MIN_BLOCK_ROWS: usize = 4;

impl Level {
    /// Gauss–Seidel on the cells of row `i` with colour `colour`
    /// (`(i + j) % 2`), `j` ascending, or descending if `reverse`.
    ///
    /// # Safety
    /// `x` points to the level's `nx·ny` cells; no other thread writes the
    /// neighbours of this row's `colour` cells or touches those cells now.
    unsafe fn relax_row(&self, x: Cells, b: &[f64], i: usize, colour: usize, reverse: bool) {
        let ny = self.ny;
        let base = i * ny;
        let first = (i + colour) % 2;
        if first >= ny {
            return;
        }
        let last = first + (ny - 1 - first) / 2 * 2;
        let general = |j: usize| {
            let k = base + j;
            // Zero couplings skipped: their index may be a far row (a wall's wrap).
            let off: f64 = self
                .couplings(i, j)
                .iter()
                .filter(|&&(_, a)| a != 0.0)
                .map(|&(n, a)| a * unsafe { x.get(n) })
                .sum();
            unsafe { x.set(k, (b[k] + off) * self.inv_diag[k]) };
        };
        match self.uniform {
            Some(u) if i > 0 && i + 1 < self.nx && ny > 2 => {
                // The end cells of the row take the boundary rule, the others
                // (`lo, lo + 2, … < hi`) the fast path.
                let lo = if first == 0 { 2 } else { first };
                let hi = if last == ny - 1 { last } else { last + 2 };
                let (start, end) = (
                    (first == 0).then_some(0),
                    (last == ny - 1).then_some(ny - 1),
                );
                let (before, after) = if reverse { (end, start) } else { (start, end) };
                if let Some(j) = before {
                    general(j);
                }
                let brow = &b[base..base + ny];
                unsafe { relax_interior(x, base, ny, brow, u, lo, hi, reverse) };
                if let Some(j) = after {
                    general(j);
                }
            }
            _ => {
                if reverse {
                    let mut j = last + 2;
                    while j > first {
                        j -= 2;
                        general(j);
                    }
                } else {
                    let mut j = first;
                    while j < ny {
                        general(j);
                        j += 2;
                    }
                }
            }
        }
    }

    /// One Gauss–Seidel sweep in interleaved red–black order (red on row `i`,
    /// black on row `i − 1`, black on the first and the last row after all
    /// the others), or its exact reverse; on all cores for a large level,
    /// with the same result.
    pub(super) fn sweep(&self, x: &mut [f64], b: &[f64], reverse: bool) {
        assert!(x.len() == self.cells() && b.len() == self.cells());
        let cells = Cells(x.as_mut_ptr());
        // The black cells of a block's first and last row: after its other
        // rows going forward, before them in reverse (last row first).
        let edges = |(a, e): (usize, usize)| unsafe {
            let rows = if reverse { [e - 1, a] } else { [a, e - 1] };
            self.relax_row(cells, b, rows[0], 1, reverse);
            if e - 1 != a {
                self.relax_row(cells, b, rows[1], 1, reverse);
            }
        };
        match self.sweep_blocks() {
            // SAFETY: `x` is borrowed mutably for the sweep; one thread.
            None => unsafe {
                if reverse {
                    edges((0, self.nx));
                }
                self.sweep_rows(cells, b, 0, self.nx, reverse);
                if !reverse {
                    edges((0, self.nx));
                }
            },
            Some(rows) => {
                let blocks: Vec<(usize, usize)> = (0..self.nx)
                    .step_by(rows)
                    .map(|a| (a, (a + rows).min(self.nx)))
                    .collect();
                // SAFETY (both phases): see `sweep_blocks`.
                let inner =
                    |&(a, e): &(usize, usize)| unsafe { self.sweep_rows(cells, b, a, e, reverse) };
                if reverse {
                    blocks.par_iter().for_each(|&block| edges(block));
                    blocks.par_iter().for_each(inner);
                } else {
                    blocks.par_iter().for_each(inner);
                    blocks.par_iter().for_each(|&block| edges(block));
                }
            }
        }
    }

    /// Rows per block of a parallel sweep, or `None` for a serial one: a
    /// level too small to split (see [`parallel::is_parallel`]), or one whose
    /// periodic x-axis has odd length (its first and last rows are then
    /// neighbours of the same colour).
    ///
    /// Why the blocks may run at once: the inner phase (`sweep_rows`) of a
    /// block writes the red cells of its rows and the black cells of its
    /// inner rows, and reads beyond the block only the black cells of the
    /// rows next to it, which are other blocks' edge rows; the edge phase
    /// writes only the black cells of edge rows and reads only red cells,
    /// which no block writes then. (The last block may have one row; it is
    /// then its own first and last row.)
    fn sweep_blocks(&self) -> Option<usize> {
        let odd_wrap = self.bx == Boundary::Periodic && self.nx % 2 == 1;
        if odd_wrap || !parallel::is_parallel(self.cells()) {
            return None;
        }
        let rows = block_cells().div_ceil(self.ny.max(1)).max(MIN_BLOCK_ROWS);
        (rows < self.nx).then_some(rows)
    }

    /// The interleaved sweep of rows `a..e` but for the black cells of rows
    /// `a` and `e − 1`: red `a`, then red `i` and black `i − 1` for `i` in
    /// `a + 1..e` (black `a` skipped); the reverse visits the same steps
    /// backwards. Going forward, the edge rows' black cells follow once every
    /// block is done; in reverse they come first.
    ///
    /// Setting the edge rows apart makes the sweep a true red–black one on a
    /// periodic x-axis too (the first row's black cells read the last row's
    /// new red ones), so that blocks of any size give the same numbers.
    ///
    /// # Safety
    /// As [`Level::relax_row`], for every row visited.
    unsafe fn sweep_rows(&self, x: Cells, b: &[f64], a: usize, e: usize, reverse: bool) {
        // The steps of the forward order: (row, colour).
        let step = |s: usize| -> (usize, usize) {
            let n = e - a;
            if s == 0 {
                (a, 0)
            } else if s == 2 * n - 1 {
                (e - 1, 1)
            } else if s % 2 == 1 {
                (a + s.div_ceil(2), 0)
            } else {
                (a + s / 2 - 1, 1)
            }
        };
        // Whether the step (row, colour) is done here: all but the black
        // cells of the edge rows.
        let keep = |(i, c): (usize, usize)| c == 0 || (i != a && i + 1 != e);
        let steps = 2 * (e - a);
        if reverse {
            for s in (0..steps).rev() {
                let (i, c) = step(s);
                if keep((i, c)) {
                    unsafe { self.relax_row(x, b, i, c, true) };
                }
            }
        } else {
            for s in 0..steps {
                let (i, c) = step(s);
                if keep((i, c)) {
                    unsafe { self.relax_row(x, b, i, c, false) };
                }
            }
        }
    }
}

/// The interior cells `lo, lo + 2, …, < hi` of the row at `base` of a
/// uniform level (its rows above and below exist), ascending, or descending
/// if `reverse`.
///
/// # Safety
/// As [`Level::relax_row`]; `1 ≤ lo`, `hi ≤ ny` and `b.len() == ny`.
#[allow(clippy::too_many_arguments)]
#[inline]
unsafe fn relax_interior(
    x: Cells,
    base: usize,
    ny: usize,
    b: &[f64],
    (ax, ay, inv_d): (f64, f64, f64),
    lo: usize,
    hi: usize,
    reverse: bool,
) {
    debug_assert!(lo >= 1 && hi <= ny && b.len() == ny && base >= ny);
    let p = x.0;
    // Cell `j` of the row from its four neighbours (a macro, not a closure:
    // the loops below must inline it).
    macro_rules! relax {
        ($j:expr) => {{
            let k = base + $j;
            unsafe {
                let off =
                    ax * (*p.add(k - ny) + *p.add(k + ny)) + ay * (*p.add(k - 1) + *p.add(k + 1));
                *p.add(k) = (b[$j] + off) * inv_d;
            }
        }};
    }
    if reverse {
        let mut j = hi;
        while j > lo {
            j -= 2;
            relax!(j);
        }
    } else {
        let mut j = lo;
        while j < hi {
            relax!(j);
            j += 2;
        }
    }
}
