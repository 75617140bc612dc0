//! The smoother: Gauss–Seidel in red–black order, rows and colours
//! interleaved (red on row `i`, then black on row `i − 1`: one pass over
//! memory per sweep), forward before the coarse correction and in exactly
//! the reverse order after it, which keeps the cycle symmetric.

use super::hierarchy::Level;

impl Level {
    /// Gauss–Seidel on the cells of row `i` with colour `colour`
    /// (`(i + j) % 2`), `j` ascending, or descending if `reverse`.
    fn relax_row(&self, x: &mut [f64], b: &[f64], i: usize, colour: usize, reverse: bool) {
        let ny = self.ny;
        let base = i * ny;
        let first = (i + colour) % 2;
        if first >= ny {
            return;
        }
        let last = first + (ny - 1 - first) / 2 * 2;
        let general = |x: &mut [f64], j: usize| {
            let k = base + j;
            let v = (b[k] + self.off(x, i, j)) * self.inv_diag[k];
            x[k] = v;
        };
        match self.uniform {
            Some(u) if i > 0 && i + 1 < self.nx && ny > 2 => {
                // The end cells of the row take the boundary rule, the others
                // (`lo, lo + 2, … < hi`) the fast path.
                let lo = if first == 0 { 2 } else { first };
                let hi = if last == ny - 1 { last } else { last + 2 };
                let brow = &b[base..base + ny];
                let (start, end) = (
                    (first == 0).then_some(0),
                    (last == ny - 1).then_some(ny - 1),
                );
                let (before, after) = if reverse { (end, start) } else { (start, end) };
                if let Some(j) = before {
                    general(x, j);
                }
                {
                    let (above, rest) = x.split_at_mut(base);
                    let (row, below) = rest.split_at_mut(ny);
                    let (up, down) = (&above[base - ny..], &below[..ny]);
                    if reverse {
                        relax_interior_rev(row, up, down, brow, u, lo, hi);
                    } else {
                        relax_interior(row, up, down, brow, u, lo, hi);
                    }
                }
                if let Some(j) = after {
                    general(x, j);
                }
            }
            _ => {
                if reverse {
                    let mut j = last + 2;
                    while j > first {
                        j -= 2;
                        general(x, j);
                    }
                } else {
                    let mut j = first;
                    while j < ny {
                        general(x, j);
                        j += 2;
                    }
                }
            }
        }
    }

    /// One Gauss–Seidel sweep in interleaved red–black order (red on row `i`,
    /// black on row `i − 1`), or its exact reverse.
    pub(super) fn sweep(&self, x: &mut [f64], b: &[f64], reverse: bool) {
        let nx = self.nx;
        // The forward order as a list of (row, colour) steps, walked either way.
        let step = |s: usize| -> (usize, usize) {
            // Steps: red 0, then for i in 1..nx: red i, black i−1; then black nx−1.
            if s == 0 {
                (0, 0)
            } else if s == 2 * nx - 1 {
                (nx - 1, 1)
            } else if s % 2 == 1 {
                (s.div_ceil(2), 0)
            } else {
                (s / 2 - 1, 1)
            }
        };
        let steps = 2 * nx;
        if reverse {
            for s in (0..steps).rev() {
                let (i, c) = step(s);
                self.relax_row(x, b, i, c, true);
            }
        } else {
            for s in 0..steps {
                let (i, c) = step(s);
                self.relax_row(x, b, i, c, false);
            }
        }
    }
}

/// The interior cells `lo, lo + 2, …, < hi` of a row of a uniform level,
/// ascending.
#[inline]
fn relax_interior(
    row: &mut [f64],
    up: &[f64],
    down: &[f64],
    b: &[f64],
    (ax, ay, inv_d): (f64, f64, f64),
    lo: usize,
    hi: usize,
) {
    let n = row.len();
    // Lets the compiler drop the bounds checks of the loop.
    assert!(lo >= 1 && hi <= n && up.len() == n && down.len() == n && b.len() == n);
    let mut j = lo;
    while j < hi {
        let off = ax * (up[j] + down[j]) + ay * (row[j - 1] + row[j + 1]);
        row[j] = (b[j] + off) * inv_d;
        j += 2;
    }
}

/// [`relax_interior`] descending.
#[inline]
fn relax_interior_rev(
    row: &mut [f64],
    up: &[f64],
    down: &[f64],
    b: &[f64],
    (ax, ay, inv_d): (f64, f64, f64),
    lo: usize,
    hi: usize,
) {
    let n = row.len();
    // Lets the compiler drop the bounds checks of the loop.
    assert!(lo >= 1 && hi <= n && up.len() == n && down.len() == n && b.len() == n);
    let mut j = hi;
    while j > lo {
        j -= 2;
        let off = ax * (up[j] + down[j]) + ay * (row[j - 1] + row[j + 1]);
        row[j] = (b[j] + off) * inv_d;
    }
}
