//! The vector Laplacian of the staggered velocity with the side conditions,
//! assembled by the kind of face (`L_FF`, `L_FX`, the wall terms `c(U)`) and
//! applied in face indices, and the implicit operator `M = I − ν dt L_FF`.

use diffphys_ops::LinearOperator;
use diffphys_tape::ArrayD;
use ndarray::{ArrayViewD, ArrayViewMutD, IxDyn};

use crate::boundaries::{FaceKind, Faces};
use crate::buffers::{for_row_blocks, give_back, scratch};
use crate::grid::{FlowGrid, Lattice};
use crate::sides::Ghost;
use crate::sparse::Csr;

/// The Laplacian of one velocity component, split by the kind of column.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ComponentLaplacian {
    /// Rows and columns over the free faces (`L_FF`).
    pub(super) ff: Csr,
    /// Rows over free faces, columns over all faces, only fixed columns (`L_FX`).
    pub(super) fx: Csr,
    /// `(free row, side, coefficient)`: the wall terms `c(U)`.
    pub(super) walls: Vec<(usize, usize, f64)>,
    /// The face of each free unknown.
    pub(super) free: Vec<usize>,
    /// Faces of the component.
    pub(super) len: usize,
    /// The component's lattice `[na, nb]` and the coefficients `(1/dx², 1/dy²)`.
    pub(super) shape: [usize; 2],
    pub(super) coeff: (f64, f64),
    /// `regular[k]`: the free face `k` reads its four lattice neighbours
    /// plainly (none missing, none itself, wrapping only along a periodic
    /// axis), so its row is the plain five-point stencil in face indices
    /// (fixed neighbours are read as they are, with the same coefficient).
    pub(super) regular: Vec<bool>,
    /// The other free faces' rows in face indices (rows and columns over all
    /// faces): the ghost and zero-gradient rows beside the sides.
    pub(super) edge: Csr,
}

/// The Laplacians of both components.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct VectorLaplacian {
    pub(crate) x: ComponentLaplacian,
    pub(crate) y: ComponentLaplacian,
}

impl VectorLaplacian {
    pub(crate) fn new(grid: &FlowGrid, faces: &Faces) -> Self {
        VectorLaplacian {
            x: ComponentLaplacian::new(grid, Lattice::FaceX, &faces.x),
            y: ComponentLaplacian::new(grid, Lattice::FaceY, &faces.y),
        }
    }

    pub(crate) fn of(&self, lattice: Lattice) -> &ComponentLaplacian {
        match lattice {
            Lattice::FaceY => &self.y,
            _ => &self.x,
        }
    }
}

impl ComponentLaplacian {
    pub(super) fn new(grid: &FlowGrid, lattice: Lattice, kinds: &[FaceKind]) -> Self {
        let [na, nb] = grid.shape(lattice);
        let free: Vec<usize> = (0..kinds.len())
            .filter(|&k| kinds[k] == FaceKind::Free)
            .collect();
        let mut index = vec![usize::MAX; kinds.len()];
        for (r, &k) in free.iter().enumerate() {
            index[k] = r;
        }
        // Along x: the normal axis of u_x, the tangential one of u_y.
        let (normal_x, periodic_x, periodic_y) = (
            lattice == Lattice::FaceX,
            grid.periodic_x(),
            grid.periodic_y(),
        );
        let (cx, cy) = (1.0 / (grid.dx * grid.dx), 1.0 / (grid.dy * grid.dy));
        let mut ff = Vec::new();
        let mut fx = Vec::new();
        let mut walls = Vec::new();
        let mut regular = vec![false; kinds.len()];
        let mut edge = Vec::new();
        // one row's entries, reused (a vector per face was most of a large
        // grid's set-up)
        let mut row = Vec::new();
        for (r, &k) in free.iter().enumerate() {
            let (a, b) = (k / nb, k % nb);
            row.clear();
            let mut plain = true;
            // (axis length, index, periodic, coefficient, is normal axis, sides low/high)
            let axes = [
                (
                    na,
                    a,
                    periodic_x,
                    cx,
                    normal_x,
                    crate::Side::Left,
                    crate::Side::Right,
                    true,
                ),
                (
                    nb,
                    b,
                    periodic_y,
                    cy,
                    !normal_x,
                    crate::Side::Bottom,
                    crate::Side::Top,
                    false,
                ),
            ];
            for (n, i, periodic, c, normal, lo, hi, along_a) in axes {
                for (step, side) in [(-1i64, lo), (1i64, hi)] {
                    let j = i as i64 + step;
                    let neighbour = if periodic {
                        Some(j.rem_euclid(n as i64) as usize)
                    } else if j >= 0 && j < n as i64 {
                        Some(j as usize)
                    } else {
                        None
                    };
                    match neighbour {
                        Some(j) => {
                            let nk = if along_a { j * nb + b } else { a * nb + j };
                            if nk == k {
                                plain = false;
                                continue;
                            }
                            ff.push((r, r, -c));
                            row.push((k, k, -c));
                            row.push((k, nk, c));
                            if index[nk] != usize::MAX {
                                ff.push((r, index[nk], c));
                            } else {
                                fx.push((r, nk, c));
                            }
                        }
                        None if normal => plain = false, // zero gradient through an open side
                        None => {
                            plain = false;
                            let Ghost { factor, wall } =
                                grid.sides.get(side).ghost(grid.normal_size(side));
                            ff.push((r, r, c * (factor - 1.0)));
                            row.push((k, k, c * (factor - 1.0)));
                            if wall != 0.0 {
                                walls.push((r, side.index(), c * wall));
                            }
                        }
                    }
                }
            }
            if plain {
                regular[k] = true;
            } else {
                edge.append(&mut row);
            }
        }
        ComponentLaplacian {
            ff: Csr::from_triplets(free.len(), free.len(), ff),
            fx: Csr::from_triplets(free.len(), kinds.len(), fx),
            walls,
            free,
            len: kinds.len(),
            shape: [na, nb],
            coeff: (cx, cy),
            regular,
            edge: Csr::from_triplets(kinds.len(), kinds.len(), edge),
        }
    }

    pub(super) fn gather(&self, u: &[f64]) -> Vec<f64> {
        self.free.iter().map(|&k| u[k]).collect()
    }

    /// `(L u)_k` at every free face `k` of `u` (face indices), 0 at the
    /// fixed faces: the five-point stencil on the regular rows (on all cores
    /// for a large lattice), the edge rows and the wall terms beside.
    pub(super) fn apply_faces(&self, u: &[f64], walls: &[f64; 4]) -> Vec<f64> {
        // every entry is written: `0 + (S u)_k`, or `0 + (−0)` off the
        // regular rows, as adding to zeros would give
        let mut out = scratch(self.len);
        self.stencil(u, Some(&self.regular), &mut out, |_, s| 0.0 + s);
        self.edge.mul_add(1.0, u, &mut out);
        for &(r, s, c) in &self.walls {
            out[self.free[r]] += c * walls[s];
        }
        out
    }

    /// `out_k += (S v)_k` where `mask` (all faces without one), `S` the
    /// plain five-point stencil with wrapped neighbour indices: `S` is
    /// symmetric, so with `v` zero off the regular rows this is also the
    /// transpose of the regular rows.
    pub(super) fn stencil_add(&self, v: &[f64], mask: Option<&[bool]>, out: &mut [f64]) {
        self.stencil(v, mask, out, |o, s| o + s);
    }

    /// `out_k = put(out_k, (S v)_k)` where `mask`, `put(out_k, −0)`
    /// elsewhere (adding `−0` leaves a sum as it is).
    fn stencil(
        &self,
        v: &[f64],
        mask: Option<&[bool]>,
        out: &mut [f64],
        put: impl Fn(f64, f64) -> f64 + Sync + Send,
    ) {
        let [na, nb] = self.shape;
        if na * nb == 0 {
            return;
        }
        let (cx, cy) = self.coeff;
        let centre = -2.0 * (cx + cy);
        // whole rows of the lattice per task, so that no entry needs a division
        for_row_blocks(out, nb, |off, block| {
            for (r, o) in block.chunks_mut(nb).enumerate() {
                let a = off / nb + r;
                let am = if a == 0 { na - 1 } else { a - 1 };
                let ap = if a + 1 == na { 0 } else { a + 1 };
                let (row, below, above) = (
                    &v[a * nb..(a + 1) * nb],
                    &v[am * nb..(am + 1) * nb],
                    &v[ap * nb..(ap + 1) * nb],
                );
                let m = mask.map(|m| &m[a * nb..(a + 1) * nb]);
                let at = |b: usize, bm: usize, bp: usize| {
                    cx * (below[b] + above[b]) + cy * (row[bm] + row[bp]) + centre * row[b]
                };
                // adding −0 leaves any sum as it is: a masked entry, branch-free
                let keep = |b: usize, s: f64| if m.is_none_or(|m| m[b]) { s } else { -0.0 };
                // the wrapped ends, then the middle as slices (vector code)
                for b in [0, nb - 1] {
                    let bm = if b == 0 { nb - 1 } else { b - 1 };
                    let bp = if b + 1 == nb { 0 } else { b + 1 };
                    o[b] = put(o[b], keep(b, at(b, bm, bp)));
                    if nb == 1 {
                        break;
                    }
                }
                if nb > 2 {
                    let mid = 1..nb - 1;
                    let (c, lo, hi) = (&row[mid.clone()], &row[..nb - 2], &row[2..]);
                    let (up, down) = (&above[mid.clone()], &below[mid.clone()]);
                    let om = &mut o[mid];
                    match m {
                        Some(m) => {
                            let m = &m[1..nb - 1];
                            for l in 0..om.len() {
                                let s =
                                    cx * (down[l] + up[l]) + cy * (lo[l] + hi[l]) + centre * c[l];
                                om[l] = put(om[l], if m[l] { s } else { -0.0 });
                            }
                        }
                        None => {
                            for l in 0..om.len() {
                                let s =
                                    cx * (down[l] + up[l]) + cy * (lo[l] + hi[l]) + centre * c[l];
                                om[l] = put(om[l], s);
                            }
                        }
                    }
                }
            }
        });
    }

    /// Adds `alpha · ∂(L u)/∂(u, U)ᵀ g` to the gradients, `g` in face indices
    /// (read at the free faces only): the transpose of [`Self::apply_faces`].
    pub(super) fn apply_faces_vjp(
        &self,
        alpha: f64,
        g: &[f64],
        grad_u: &mut [f64],
        grad_walls: &mut [f64; 4],
    ) {
        let mut masked = scratch(g.len());
        masked
            .iter_mut()
            .zip(g.iter().zip(&self.regular))
            .for_each(|(m, (&v, &r))| *m = if r { alpha * v } else { 0.0 });
        self.stencil_add(&masked, None, grad_u);
        give_back(masked);
        self.edge.mul_t_add(alpha, g, grad_u);
        for &(r, s, c) in &self.walls {
            grad_walls[s] += alpha * c * g[self.free[r]];
        }
    }

    /// `(L u)_F` on the free faces.
    pub(super) fn apply(&self, u: &[f64], walls: &[f64; 4]) -> Vec<f64> {
        let lu = self.apply_faces(u, walls);
        self.gather(&lu)
    }

    /// `(L_FX u + c(U))_F`: what the fixed faces and walls add.
    pub(super) fn boundary_terms(&self, u: &[f64], walls: &[f64; 4]) -> Vec<f64> {
        let mut out = vec![0.0; self.free.len()];
        self.fx.mul_add(1.0, u, &mut out);
        for &(r, s, c) in &self.walls {
            out[r] += c * walls[s];
        }
        out
    }

    /// Adds `alpha · ∂(L u)_F/∂(u, U)ᵀ g_F` to the gradients.
    pub(super) fn apply_vjp(
        &self,
        alpha: f64,
        g_free: &[f64],
        grad_u: &mut [f64],
        grad_walls: &mut [f64; 4],
        with_ff: bool,
    ) {
        if with_ff {
            let mut t = vec![0.0; self.free.len()];
            self.ff.mul_t_add(alpha, g_free, &mut t);
            for (r, &k) in self.free.iter().enumerate() {
                grad_u[k] += t[r];
            }
        }
        self.fx.mul_t_add(alpha, g_free, grad_u);
        for &(r, s, c) in &self.walls {
            grad_walls[s] += alpha * c * g_free[r];
        }
    }
}

/// The implicit operator `M = I − ν dt L_FF` of one component.
pub(super) struct Helmholtz<'a> {
    pub(super) lap: &'a ComponentLaplacian,
    pub(super) nu_dt: f64,
    pub(super) shape: [usize; 1],
}

impl LinearOperator<f64> for Helmholtz<'_> {
    fn name(&self) -> &str {
        "viscosity (I − ν dt L)"
    }
    fn input_shape(&self) -> &[usize] {
        &self.shape
    }
    fn output_shape(&self) -> &[usize] {
        &self.shape
    }
    fn apply_into(&self, x: ArrayViewD<'_, f64>, mut out: ArrayViewMutD<'_, f64>) {
        let x = x.as_standard_layout();
        let xs = x.as_slice().expect("standard");
        let o = out.as_slice_mut().expect("contiguous output");
        o.copy_from_slice(xs);
        self.lap.ff.mul_add(-self.nu_dt, xs, o);
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, f64>, out: ArrayViewMutD<'_, f64>) {
        self.apply_into(y, out);
    }
    fn is_symmetric(&self) -> bool {
        true
    }
    fn diagonal(&self) -> Option<ArrayD<f64>> {
        let d: Vec<f64> = self
            .lap
            .ff
            .diagonal()
            .iter()
            .map(|v| 1.0 - self.nu_dt * v)
            .collect();
        Some(ArrayD::from_shape_vec(IxDyn(&self.shape), d).expect("one per unknown"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boundaries::Obstacle;
    use crate::diffusion::{default_viscosity_solver, Diffusion};
    use crate::sides::{Boundary, Sides};

    /// `(L u)_F` from the assembled blocks `L_FF u_F + L_FX u + c(U)`.
    fn assembled(l: &ComponentLaplacian, u: &[f64], walls: &[f64; 4]) -> Vec<f64> {
        let mut out = vec![0.0; l.free.len()];
        l.ff.mul_add(1.0, &l.gather(u), &mut out);
        l.fx.mul_add(1.0, u, &mut out);
        for &(r, s, c) in &l.walls {
            out[r] += c * walls[s];
        }
        out
    }

    /// The viscous operators of a few grids: walls of every kind with an
    /// obstacle, periodic boxes, a channel periodic along x.
    fn operators() -> Vec<Diffusion> {
        let grid = |n: usize, m: usize, size: [f64; 2], sides: Sides| FlowGrid {
            nx: n,
            ny: m,
            dx: size[0] / n as f64,
            dy: size[1] / m as f64,
            sides,
        };
        let mixed = |n: usize, m: usize| {
            let g = grid(
                n,
                m,
                [1.0, 0.8],
                Sides {
                    left: Boundary::no_slip(),
                    right: Boundary::outflow(),
                    bottom: Boundary::moving_wall(0.5),
                    top: Boundary::free_slip(),
                },
            );
            let solid = Obstacle::rectangle([0.4, 0.3], [0.7, 0.65])
                .rasterise(&g)
                .unwrap();
            (g, solid)
        };
        let plain = |g: FlowGrid| {
            let solid = ndarray::Array2::from_elem((g.nx, g.ny), false);
            (g, solid)
        };
        let periodic_x = Sides {
            left: Boundary::periodic(),
            right: Boundary::periodic(),
            bottom: Boundary::no_slip(),
            top: Boundary::moving_wall(-0.3),
        };
        [
            mixed(8, 7),
            // large enough that the stencil splits across threads
            mixed(300, 240),
            plain(grid(6, 5, [1.0, 1.0], Sides::periodic())),
            plain(grid(2, 3, [1.0, 1.0], Sides::periodic())),
            plain(grid(9, 7, [1.0, 1.0], periodic_x)),
        ]
        .into_iter()
        .map(|(g, solid)| {
            Diffusion::new(&g, &Faces::classify(&g, &solid), default_viscosity_solver())
        })
        .collect()
    }

    /// The face-index path (five-point rows, edge rows, wall terms) is the
    /// assembled Laplacian, and its transpose is the assembled transpose.
    #[test]
    fn stencil_rows_match_the_assembled_blocks() {
        let walls = [0.3, -0.7, 1.1, 0.4];
        for diffusion in operators() {
            for l in [&diffusion.laplacian().x, &diffusion.laplacian().y] {
                let u: Vec<f64> = (0..l.len).map(|k| ((k * 37 % 101) as f64).sin()).collect();
                let fast = l.apply(&u, &walls);
                let slow = assembled(l, &u, &walls);
                let scale = slow.iter().fold(1.0f64, |m, v| m.max(v.abs()));
                for (a, b) in fast.iter().zip(&slow) {
                    assert!((a - b).abs() <= 1e-12 * scale, "L u: {a} against {b}");
                }
                // transpose: the free rows' g against L_FFᵀ and L_FXᵀ
                let g: Vec<f64> = (0..l.len).map(|k| ((k * 53 % 89) as f64).cos()).collect();
                let (mut fast_u, mut fast_w) = (vec![0.0; l.len], [0.0; 4]);
                l.apply_faces_vjp(0.7, &g, &mut fast_u, &mut fast_w);
                let (mut slow_u, mut slow_w) = (vec![0.0; l.len], [0.0; 4]);
                l.apply_vjp(0.7, &l.gather(&g), &mut slow_u, &mut slow_w, true);
                for (a, b) in fast_u.iter().zip(&slow_u).chain(fast_w.iter().zip(&slow_w)) {
                    assert!((a - b).abs() <= 1e-12 * scale, "Lᵀ g: {a} against {b}");
                }
            }
        }
    }
}
