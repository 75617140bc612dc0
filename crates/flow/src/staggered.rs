//! The divergence and the gradient of the staggered grid, in face and cell
//! indices: `D` (cells ← faces) and `G = −Dᵀ` (faces ← cells), over all
//! faces or over the free ones only (`D_F`, `G_F`, fixed faces counting as
//! zero). The projection, the incremental splitting and the diagnostics are
//! built on them. Rows of cells or faces run on all cores for a large grid,
//! each entry summed in the same order wherever it runs.

use crate::boundaries::{FaceKind, Faces};
use crate::buffers::{for_row_blocks, scratch, zeros};
use crate::grid::FlowGrid;

/// The face kinds the kernels skip by: the grid's, or all free (where every
/// face counts, or every face is free: nothing to leave out).
enum FaceKinds<'a> {
    Of(&'a Faces),
    AllFree(Vec<FaceKind>),
}

impl<'a> FaceKinds<'a> {
    /// Whether fixed faces are skipped, and the kinds.
    fn of(free: Option<&'a Faces>, ny: usize, nfy: usize) -> (bool, Self) {
        match free.filter(|f| !f.all_free()) {
            Some(f) => (true, FaceKinds::Of(f)),
            None => (false, FaceKinds::AllFree(vec![FaceKind::Free; ny.max(nfy)])),
        }
    }

    /// The kinds of x-face row `f` (`ny` faces).
    fn x(&self, f: usize, ny: usize) -> &[FaceKind] {
        match self {
            FaceKinds::Of(faces) => &faces.x[f * ny..(f + 1) * ny],
            FaceKinds::AllFree(v) => &v[..ny],
        }
    }

    /// The kinds of the y-faces of column `i` (`nfy` faces).
    fn y(&self, i: usize, nfy: usize) -> &[FaceKind] {
        match self {
            FaceKinds::Of(faces) => &faces.y[i * nfy..(i + 1) * nfy],
            FaceKinds::AllFree(v) => &v[..nfy],
        }
    }
}

/// `D u` on the cells, over all faces: `(u_x[i+1,j] − u_x[i,j])/dx + (u_y[i,j+1] − u_y[i,j])/dy`.
/// With `free` faces given, fixed faces count as zero (`D_F`).
pub(crate) fn divergence_wide(
    g: &FlowGrid,
    free: Option<&Faces>,
    ux: &[f64],
    uy: &[f64],
) -> Vec<f64> {
    let (nx, ny) = (g.nx, g.ny);
    let [nfx, _] = g.shape_x();
    let [_, nfy] = g.shape_y();
    let (free_only, kinds) = FaceKinds::of(free, ny, nfy);
    // Each cell's faces (at most two) in ascending face order with the sign
    // of their flow (+ where the cell is the face's low side): the order in
    // which a loop over the faces would add them, so the sums are that loop's.
    type Touching = ([(usize, bool); 2], usize);
    let touching =
        |n: usize, nf: usize, cells: &dyn Fn(usize) -> (Option<usize>, Option<usize>)| {
            let mut of: Vec<Touching> = vec![([(0, false); 2], 0); n];
            for f in 0..nf {
                let (lo, hi) = cells(f);
                for (cell, low) in [(lo, true), (hi, false)] {
                    if let Some(c) = cell {
                        let (faces, len) = &mut of[c];
                        faces[*len] = (f, low);
                        *len += 1;
                    }
                }
            }
            of
        };
    let x_of = touching(nx, nfx, &|f| g.x_face_cells(f));
    let y_of = touching(ny, nfy, &|f| g.y_face_cells(f));
    let mut d = zeros(nx * ny);
    if ny == 0 {
        return d;
    }
    // `acc − flow` is `acc + (−flow)` exactly, and adding −0 leaves any sum
    // as it is (a skipped face)
    let term = |v: f64, h: f64, low: bool, skip: bool| {
        if skip {
            -0.0
        } else if low {
            v / h
        } else {
            -(v / h)
        }
    };
    // each cell's two y-face terms as indices into `[plus, minus, −0]`
    // (a missing face reads −0, which leaves a sum as it is): no branch in
    // the row loop below
    let pick: Vec<[usize; 2]> = y_of
        .iter()
        .map(|(faces, len)| {
            let at = |t: usize| {
                if t < *len {
                    let (f, low) = faces[t];
                    if low {
                        f
                    } else {
                        nfy + f
                    }
                } else {
                    2 * nfy
                }
            };
            [at(0), at(1)]
        })
        .collect();
    for_row_blocks(&mut d, ny, |off, block| {
        let mut terms = vec![-0.0; 2 * nfy + 1];
        for (r, row) in block.chunks_mut(ny).enumerate() {
            let i = off / ny + r;
            // the x-faces of the row, whole face rows at a time
            let (faces_x, len) = &x_of[i];
            for &(f, low) in &faces_x[..*len] {
                let (u, kinds) = (&ux[f * ny..(f + 1) * ny], kinds.x(f, ny));
                for ((acc, &v), kind) in row.iter_mut().zip(u).zip(kinds) {
                    *acc += term(v, g.dx, low, free_only && *kind != FaceKind::Free);
                }
            }
            // the y-faces of the row: each face's term for the cell on its
            // low side and on its high side, then each cell's two
            let (u, kinds) = (&uy[i * nfy..(i + 1) * nfy], kinds.y(i, nfy));
            let (plus, rest) = terms.split_at_mut(nfy);
            for (((lo, hi), &v), kind) in plus.iter_mut().zip(rest.iter_mut()).zip(u).zip(kinds) {
                let skip = free_only && *kind != FaceKind::Free;
                *lo = term(v, g.dy, true, skip);
                *hi = term(v, g.dy, false, skip);
            }
            for (acc, &[t0, t1]) in row.iter_mut().zip(&pick) {
                *acc += terms[t0];
                *acc += terms[t1];
            }
        }
    });
    d
}

/// `G p` on the faces (`(p_hi − p_lo)/h`, zero outside); with `free` faces
/// given, on the free faces only (`G_F`). Rows of faces on all cores for a large grid.
pub(crate) fn gradient_wide(g: &FlowGrid, free: Option<&Faces>, p: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let [nfx, _] = g.shape_x();
    let [_, nfy] = g.shape_y();
    let (free_only, _) = FaceKinds::of(free, g.ny, nfy);
    // every face is written, except the fixed ones when they are skipped
    // (and all of them on a grid without a row)
    let written = !free_only && g.ny > 0 && nfy > 0;
    let fresh = |n: usize| if written { scratch(n) } else { zeros(n) };
    let mut gx = fresh(nfx * g.ny);
    let mut gy = fresh(g.nx * nfy);
    gradient_into(g, free, p, &mut gx, &mut gy, |out, v| *out = v);
    (gx, gy)
}

/// `u −= c G p` on the faces (`u_F −= c (G_F p)_F` with `free` faces given):
/// [`gradient_wide`]'s differences subtracted where they are computed, the
/// same bits as subtracting `c` times its output (and, for `c = 1`, the
/// output itself: `1 · g` is `g`), without the two arrays between.
pub(crate) fn subtract_gradient_wide(
    g: &FlowGrid,
    free: Option<&Faces>,
    p: &[f64],
    c: f64,
    ux: &mut [f64],
    uy: &mut [f64],
) {
    gradient_into(g, free, p, ux, uy, |out, v| *out -= c * v);
}

/// `put(out_f, (G p)_f)` at every face `f` of `gx`, `gy` (the free ones
/// with `free` given).
fn gradient_into(
    g: &FlowGrid,
    free: Option<&Faces>,
    p: &[f64],
    gx: &mut [f64],
    gy: &mut [f64],
    put: impl Fn(&mut f64, f64) + Sync + Send,
) {
    let (nx, ny) = (g.nx, g.ny);
    let [_, nfy] = g.shape_y();
    let (free_only, kinds) = FaceKinds::of(free, ny, nfy);
    if ny == 0 || nfy == 0 {
        return;
    }
    debug_assert_eq!(gy.len(), nx * nfy);
    // `at(c)` is the pressure of cell c, 0 outside: the difference of the
    // two, divided by h, written out per case so that a row is one loop
    let zeros = vec![0.0; ny];
    let row_of = |c: Option<usize>| c.map_or(&zeros[..], |i| &p[i * ny..(i + 1) * ny]);
    for_row_blocks(gx, ny, |off, block| {
        for (r, row) in block.chunks_mut(ny).enumerate() {
            let f = off / ny + r;
            let (lo, hi) = g.x_face_cells(f);
            let (pl, ph) = (row_of(lo), row_of(hi));
            let kinds = kinds.x(f, ny);
            for (((out, &a), &b), kind) in row.iter_mut().zip(ph).zip(pl).zip(kinds) {
                if !(free_only && *kind != FaceKind::Free) {
                    put(out, (a - b) / g.dx);
                }
            }
        }
    });
    // along y: the cells of each face as indices into the row with a zero
    // appended (index ny), the same differences
    let index = |c: Option<usize>| c.unwrap_or(ny);
    let (lo_of, hi_of): (Vec<usize>, Vec<usize>) = (0..nfy)
        .map(|f| {
            let (lo, hi) = g.y_face_cells(f);
            (index(lo), index(hi))
        })
        .unzip();
    let shift = shifted_run(&lo_of, &hi_of);
    for_row_blocks(gy, nfy, |off, block| {
        let mut pi = vec![0.0; ny + 1];
        for (r, row) in block.chunks_mut(nfy).enumerate() {
            let i = off / nfy + r;
            pi[..ny].copy_from_slice(&p[i * ny..(i + 1) * ny]);
            let kinds = kinds.y(i, nfy);
            let face = |f: usize, out: &mut f64| {
                if !(free_only && kinds[f] != FaceKind::Free) {
                    put(out, (pi[hi_of[f]] - pi[lo_of[f]]) / g.dy);
                }
            };
            match &shift {
                // the faces whose cells are `f − 1` and `f`: the same
                // differences read as two slices (vector code)
                Some(run) if !free_only => {
                    let (a, b) = (run.start, run.end);
                    (0..a).for_each(|f| face(f, &mut row[f]));
                    let (hi, lo) = (&pi[a..b], &pi[a - 1..b - 1]);
                    for ((out, &h), &l) in row[a..b].iter_mut().zip(hi).zip(lo) {
                        put(out, (h - l) / g.dy);
                    }
                    (b..nfy).for_each(|f| face(f, &mut row[f]));
                }
                _ => (0..nfy).for_each(|f| face(f, &mut row[f])),
            }
        }
    });
}

/// The longest run of faces `f` whose cells are `f − 1` (low) and `f`
/// (high), if any: the interior of a row of y-faces.
fn shifted_run(lo_of: &[usize], hi_of: &[usize]) -> Option<std::ops::Range<usize>> {
    let plain = |f: usize| f >= 1 && hi_of[f] == f && lo_of[f] == f - 1;
    let mut best: Option<std::ops::Range<usize>> = None;
    let mut f = 0;
    while f < hi_of.len() {
        if plain(f) {
            let start = f;
            while f < hi_of.len() && plain(f) {
                f += 1;
            }
            if best.as_ref().is_none_or(|r| f - start > r.len()) {
                best = Some(start..f);
            }
        } else {
            f += 1;
        }
    }
    best
}
