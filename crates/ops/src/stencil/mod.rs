//! Linear stencil operators on cell-centred fields: Laplacian, gradient,
//! divergence and explicit diffusion, in 1D and 2D, behind [`LinearOperator`].
//!
//! Every stencil resolves the neighbour of a cell across a domain edge once, from
//! the axis' [`Boundary`]: periodic axes wrap around, the others read a ghost cell
//! whose value is a fixed multiple of the edge cell's (`−1` for zero Dirichlet,
//! `+1` for closed walls). The inner loops then run over contiguous rows with no
//! branch; the edge cells are computed separately.
//!
//! ```
//! use diffphys_ops::{stencil::Laplacian2, Boundary, Grid2, LinearOperator};
//! use ndarray::ArrayD;
//!
//! let grid = Grid2::new(4, 3, 0.5, 0.25, Boundary::ZeroDirichlet)?;
//! let a = Laplacian2::negative(grid); // −∇², symmetric positive definite here
//! let x = ArrayD::<f64>::ones(vec![4, 3]);
//! let ax = a.apply(x.view())?;
//! assert_eq!(ax[[1, 1]], 0.0); // −∇² of a constant vanishes inside…
//! assert!(ax[[0, 0]] > 0.0); // …but not next to a wall, where the field drops to 0
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```
//!
//! [`LinearOperator`]: crate::LinearOperator

mod diffusion;
mod divergence;
mod gradient;
mod laplacian;
mod masked;

pub use diffusion::{DiffusionParams, ExplicitDiffusion1, ExplicitDiffusion2};
pub use divergence::{Divergence1, Divergence2};
pub use gradient::{Gradient1, Gradient2};
pub use laplacian::{Laplacian1, Laplacian2};
pub use masked::Masked;

use diffphys_tape::Real;
use ndarray::{ArrayViewD, ArrayViewMutD};

use crate::Boundary;

/// How a stencil closes an axis at its two ends.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Ghost {
    /// The axis wraps around.
    Wrap,
    /// The ghost cell beyond an edge holds `s ×` the edge cell's value.
    Mirror(f64),
}

impl Ghost {
    /// The closure of a scalar field's stencil (Laplacian, gradient): periodic
    /// wraps, zero Dirichlet mirrors with `−1` (zero on the wall), closed walls
    /// with `+1` (zero normal derivative).
    pub(crate) fn scalar(b: Boundary) -> Self {
        match b {
            Boundary::Periodic => Ghost::Wrap,
            Boundary::ZeroDirichlet => Ghost::Mirror(-1.0),
            Boundary::Closed => Ghost::Mirror(1.0),
        }
    }

    /// The closure that makes a central difference the negative transpose of the
    /// one with `self`: `Gₛᵀ = −G₋ₛ`.
    pub(crate) fn flipped(self) -> Self {
        match self {
            Ghost::Wrap => Ghost::Wrap,
            Ghost::Mirror(s) => Ghost::Mirror(-s),
        }
    }
}

/// The cell a stencil reads across one side of cell `i`, and the weight of its value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Neighbour {
    /// Index along the axis (the edge cell itself for a mirrored ghost).
    pub(crate) idx: usize,
    /// The ghost's factor: `1` inside the domain and for wrapped neighbours.
    pub(crate) w: f64,
}

/// The neighbour of cell `i` on the low side of an axis of `n` cells.
pub(crate) fn prev(i: usize, n: usize, ghost: Ghost) -> Neighbour {
    if i > 0 {
        return Neighbour { idx: i - 1, w: 1.0 };
    }
    match ghost {
        Ghost::Wrap => Neighbour { idx: n - 1, w: 1.0 },
        Ghost::Mirror(s) => Neighbour { idx: 0, w: s },
    }
}

/// The neighbour of cell `i` on the high side of an axis of `n` cells.
pub(crate) fn next(i: usize, n: usize, ghost: Ghost) -> Neighbour {
    if i + 1 < n {
        return Neighbour { idx: i + 1, w: 1.0 };
    }
    match ghost {
        Ghost::Wrap => Neighbour { idx: 0, w: 1.0 },
        Ghost::Mirror(s) => Neighbour { idx: i, w: s },
    }
}

/// The columns `{0, n − 1}` without repetition: the cells of a row whose
/// neighbours need the boundary.
pub(crate) fn edge_indices(n: usize) -> impl Iterator<Item = usize> {
    std::iter::once(0).chain((n > 1).then_some(n - 1))
}

/// Runs `kernel` on the row-major slices of `x` and `out`, copying through
/// standard-layout buffers when either view is not one.
pub(crate) fn with_slices<T: Real, R>(
    x: ArrayViewD<'_, T>,
    mut out: ArrayViewMutD<'_, T>,
    kernel: impl FnOnce(&[T], &mut [T]) -> R,
) -> R {
    let x = x.as_standard_layout();
    let xs = x.as_slice().expect("standard layout is contiguous");
    if let Some(o) = out.as_slice_mut() {
        return kernel(xs, o);
    }
    let mut buf = vec![T::zero(); out.len()];
    let r = kernel(xs, &mut buf);
    for (o, b) in out.iter_mut().zip(buf) {
        *o = b;
    }
    r
}

/// Merges the entries of one matrix row that fall on the same column, keeping the
/// diagonal and dropping exact zeros elsewhere, and appends them to `triplets`.
pub(crate) fn push_row<T: Real>(
    triplets: &mut Vec<(usize, usize, T)>,
    row: usize,
    entries: &mut [(usize, f64)],
) {
    entries.sort_by_key(|e| e.0);
    let mut k = 0;
    while k < entries.len() {
        let col = entries[k].0;
        let mut v = 0.0;
        while k < entries.len() && entries[k].0 == col {
            v += entries[k].1;
            k += 1;
        }
        if v != 0.0 || col == row {
            triplets.push((row, col, T::from_f64(v)));
        }
    }
}

/// `out ±= c·(x[i+1] − x[i−1])` along `axis` (0: across rows, 1: within rows) of a
/// row-major `nx × ny` array: `c = ±1/(2h)` gives a central difference. Writes
/// (`ACC = false`) or accumulates (`ACC = true`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn central_difference<T: Real, const ACC: bool>(
    x: &[T],
    out: &mut [T],
    nx: usize,
    ny: usize,
    axis: usize,
    c: f64,
    ghost: Ghost,
) {
    let ct = T::from_f64(c);
    let put = |o: &mut T, v: T| {
        if ACC {
            *o += v;
        } else {
            *o = v;
        }
    };
    if axis == 0 {
        for i in 0..nx {
            let (p, q) = (prev(i, nx, ghost), next(i, nx, ghost));
            let (wp, wq) = (ct * T::from_f64(p.w), ct * T::from_f64(q.w));
            let xp = &x[p.idx * ny..(p.idx + 1) * ny];
            let xq = &x[q.idx * ny..(q.idx + 1) * ny];
            let o = &mut out[i * ny..(i + 1) * ny];
            for ((o, &a), &b) in o.iter_mut().zip(xp).zip(xq) {
                put(o, wq * b - wp * a);
            }
        }
    } else {
        let edges: Vec<(usize, Neighbour, Neighbour)> = edge_indices(ny)
            .map(|j| (j, prev(j, ny, ghost), next(j, ny, ghost)))
            .collect();
        for i in 0..nx {
            let xc = &x[i * ny..(i + 1) * ny];
            let o = &mut out[i * ny..(i + 1) * ny];
            for &(j, l, r) in &edges {
                let v = ct * (T::from_f64(r.w) * xc[r.idx] - T::from_f64(l.w) * xc[l.idx]);
                put(&mut o[j], v);
            }
            if ny > 2 {
                for (o, w) in o[1..ny - 1].iter_mut().zip(xc.windows(3)) {
                    put(o, ct * (w[2] - w[0]));
                }
            }
        }
    }
}

/// The nonzeros of [`central_difference`] as `(row, column, value)`, with rows
/// offset by `row0` and columns by `col0` (component blocks of vector fields).
#[allow(clippy::too_many_arguments)]
pub(crate) fn central_difference_entries(
    nx: usize,
    ny: usize,
    axis: usize,
    c: f64,
    ghost: Ghost,
    row0: usize,
    col0: usize,
    mut sink: impl FnMut(usize, [(usize, f64); 2]),
) {
    for i in 0..nx {
        for j in 0..ny {
            let (l, r) = if axis == 0 {
                let (p, q) = (prev(i, nx, ghost), next(i, nx, ghost));
                ((p.idx * ny + j, p.w), (q.idx * ny + j, q.w))
            } else {
                let (p, q) = (prev(j, ny, ghost), next(j, ny, ghost));
                ((i * ny + p.idx, p.w), (i * ny + q.idx, q.w))
            };
            sink(
                row0 + i * ny + j,
                [(col0 + r.0, c * r.1), (col0 + l.0, -c * l.1)],
            );
        }
    }
}

/// Checks shared by the stencil tests.
// Tested here, not in crates/ops/tests: the neighbour and row helpers are
// private to the crate.
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbours_across_each_boundary() {
        assert_eq!(prev(0, 5, Ghost::Wrap), Neighbour { idx: 4, w: 1.0 });
        assert_eq!(next(4, 5, Ghost::Wrap), Neighbour { idx: 0, w: 1.0 });
        assert_eq!(
            prev(0, 5, Ghost::Mirror(-1.0)),
            Neighbour { idx: 0, w: -1.0 }
        );
        assert_eq!(next(4, 5, Ghost::Mirror(1.0)), Neighbour { idx: 4, w: 1.0 });
        assert_eq!(next(2, 5, Ghost::Mirror(1.0)), Neighbour { idx: 3, w: 1.0 });
        assert_eq!(edge_indices(1).collect::<Vec<_>>(), vec![0]);
        assert_eq!(edge_indices(4).collect::<Vec<_>>(), vec![0, 3]);
    }

    #[test]
    fn rows_merge_duplicate_columns() {
        let mut t: Vec<(usize, usize, f64)> = Vec::new();
        push_row(&mut t, 1, &mut [(0, 1.0), (1, -2.0), (0, 1.0), (2, 0.0)]);
        assert_eq!(t, vec![(1, 0, 2.0), (1, 1, -2.0)]);
    }
}
