//! The levels of the cycle: each level's 5-point operator (couplings, wall
//! terms, diagonal and the active cells of a mask), built from a Laplacian or
//! a staggered grid's pressure operator, and the coarsening that builds the
//! next level from it.

use crate::mac::MacGrid;
use crate::{Boundary, Grid2};

#[cfg(doc)]
use crate::stencil::Laplacian2;

/// One grid level: the couplings `a` across the east (`+x`) and north (`+y`)
/// face of every cell (wrapping on a periodic axis, 0 where there is no
/// face), the diagonal, the wall terms, and the active cells.
#[derive(Debug, Clone)]
pub(super) struct Level {
    pub(super) nx: usize,
    pub(super) ny: usize,
    pub(super) bx: Boundary,
    pub(super) by: Boundary,
    pub(super) fx: Vec<f64>,
    pub(super) fy: Vec<f64>,
    pub(super) diag: Vec<f64>,
    /// `1/d` (0 where `d = 0`: an active cell with no face and no wall, whose
    /// value the cycle leaves at 0).
    pub(super) inv_diag: Vec<f64>,
    /// The wall terms of the x-walls and the y-walls.
    pub(super) wall: [Vec<f64>; 2],
    /// The cells' widths along x and y in units of the finest spacing
    /// (`2^l`, or less for the last cell of an odd axis).
    pub(super) widths: [Vec<f64>; 2],
    /// `None`: every cell is active.
    pub(super) active: Option<Vec<bool>>,
    /// `(a_x, a_y, 1/d)` shared by every interior cell, if they all agree (no
    /// mask): the fast path of the smoother and the residual.
    pub(super) uniform: Option<(f64, f64, f64)>,
}

impl Level {
    /// A level from its couplings and wall terms (diagonal, inverse and the
    /// uniform test derived).
    pub(super) fn from_faces(
        (nx, ny): (usize, usize),
        (bx, by): (Boundary, Boundary),
        fx: Vec<f64>,
        fy: Vec<f64>,
        wall: [Vec<f64>; 2],
        widths: [Vec<f64>; 2],
        active: Option<Vec<bool>>,
    ) -> Self {
        let mut level = Level {
            nx,
            ny,
            bx,
            by,
            fx,
            fy,
            diag: Vec::new(),
            inv_diag: Vec::new(),
            wall,
            widths,
            active,
            uniform: None,
        };
        let mut diag = vec![0.0; nx * ny];
        for i in 0..nx {
            for j in 0..ny {
                let k = i * ny + j;
                diag[k] = if level.is_active(k) {
                    level.couplings(i, j).iter().map(|&(_, a)| a).sum::<f64>()
                        + level.wall[0][k]
                        + level.wall[1][k]
                } else {
                    1.0
                };
            }
        }
        level.inv_diag = diag
            .iter()
            .map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 })
            .collect();
        if level.widths[0].first().is_some_and(|&w| w > 1.0) {
            // A coarse level: no correction on inactive cells.
            for k in 0..nx * ny {
                if !level.is_active(k) {
                    level.inv_diag[k] = 0.0;
                }
            }
        }
        level.diag = diag;
        level.uniform = level.find_uniform();
        level
    }

    pub(super) fn cells(&self) -> usize {
        self.nx * self.ny
    }

    pub(super) fn is_active(&self, k: usize) -> bool {
        self.active.as_ref().is_none_or(|a| a[k])
    }

    /// The four neighbours of `(i, j)` with their couplings (0 where there is
    /// no face; a neighbour index is then the cell itself).
    #[inline]
    pub(super) fn couplings(&self, i: usize, j: usize) -> [(usize, f64); 4] {
        let (nx, ny) = (self.nx, self.ny);
        let k = i * ny + j;
        let west = if i > 0 { i - 1 } else { nx - 1 };
        let east = if i + 1 < nx { i + 1 } else { 0 };
        let south = if j > 0 { j - 1 } else { ny - 1 };
        let north = if j + 1 < ny { j + 1 } else { 0 };
        [
            (west * ny + j, self.fx[west * ny + j]),
            (east * ny + j, self.fx[k]),
            (i * ny + south, self.fy[i * ny + south]),
            (i * ny + north, self.fy[k]),
        ]
    }

    /// The couplings shared by all interior cells, if there is no mask and
    /// they agree.
    pub(super) fn find_uniform(&self) -> Option<(f64, f64, f64)> {
        if self.active.is_some() {
            return None;
        }
        let (nx, ny) = (self.nx, self.ny);
        if nx < 3 || ny < 3 {
            return Some((0.0, 0.0, 0.0));
        }
        let (ax, ay) = (self.fx[ny + 1], self.fy[ny + 1]);
        let d = self.diag[ny + 1];
        for i in 1..nx - 1 {
            for j in 1..ny - 1 {
                let k = i * ny + j;
                let same = self.fx[k] == ax
                    && self.fx[k - ny] == ax
                    && self.fy[k] == ay
                    && self.fy[k - 1] == ay
                    && self.diag[k] == d;
                if !same {
                    return None;
                }
            }
        }
        (d > 0.0).then_some((ax, ay, 1.0 / d))
    }

    /// The level of `−∇²` on `grid` ([`Laplacian2::negative`]): couplings
    /// `1/h²`, wall terms `2/h²` at zero Dirichlet walls (the ghost `−x`).
    pub(super) fn laplacian(grid: &Grid2) -> Self {
        let (nx, ny) = (grid.nx, grid.ny);
        let (cx, cy) = (1.0 / (grid.dx * grid.dx), 1.0 / (grid.dy * grid.dy));
        let mut fx = vec![0.0; nx * ny];
        let mut fy = vec![0.0; nx * ny];
        let mut wall = [vec![0.0; nx * ny], vec![0.0; nx * ny]];
        let dirichlet_x = grid.boundary_x == Boundary::ZeroDirichlet;
        let dirichlet_y = grid.boundary_y == Boundary::ZeroDirichlet;
        let periodic_x = grid.boundary_x == Boundary::Periodic;
        let periodic_y = grid.boundary_y == Boundary::Periodic;
        for i in 0..nx {
            for j in 0..ny {
                let k = i * ny + j;
                if i + 1 < nx || (periodic_x && nx > 1) {
                    fx[k] = cx;
                }
                if j + 1 < ny || (periodic_y && ny > 1) {
                    fy[k] = cy;
                }
                for (axis, (edge, n, c, dirichlet)) in
                    [(i, nx, cx, dirichlet_x), (j, ny, cy, dirichlet_y)]
                        .into_iter()
                        .enumerate()
                {
                    if dirichlet {
                        let walls = usize::from(edge == 0) + usize::from(edge + 1 == n);
                        wall[axis][k] += 2.0 * c * walls as f64;
                    }
                }
            }
        }
        Level::from_faces(
            (nx, ny),
            (grid.boundary_x, grid.boundary_y),
            fx,
            fy,
            wall,
            [vec![1.0; nx], vec![1.0; ny]],
            None,
        )
    }

    /// The level of a MAC grid's pressure operator ([`MacGrid::pressure_operator`]):
    /// coupling `1/h²` across each open face between two cells, wall term
    /// `1/h²` for each open face to the outside (zero pressure at the ghost
    /// centre), inactive cells as identity rows.
    pub(super) fn mac(mac: &MacGrid) -> Self {
        let grid = mac.grid();
        let (nx, ny) = (grid.nx, grid.ny);
        let (cx, cy) = (1.0 / (grid.dx * grid.dx), 1.0 / (grid.dy * grid.dy));
        let mut fx = vec![0.0; nx * ny];
        let mut fy = vec![0.0; nx * ny];
        let mut wall = [vec![0.0; nx * ny], vec![0.0; nx * ny]];
        let open_x = mac.open_faces_x();
        for ((f, j), &open) in open_x.indexed_iter().map(|(ix, o)| ((ix[0], ix[1]), o)) {
            if !open {
                continue;
            }
            match mac.face_cells_x(f) {
                (Some(lo), Some(hi)) if lo != hi => fx[lo * ny + j] += cx,
                (Some(c), None) | (None, Some(c)) => wall[0][c * ny + j] += cx,
                _ => {}
            }
        }
        let open_y = mac.open_faces_y();
        for ((i, f), &open) in open_y.indexed_iter().map(|(ix, o)| ((ix[0], ix[1]), o)) {
            if !open {
                continue;
            }
            match mac.face_cells_y(f) {
                (Some(lo), Some(hi)) if lo != hi => fy[i * ny + lo] += cy,
                (Some(c), None) | (None, Some(c)) => wall[1][i * ny + c] += cy,
                _ => {}
            }
        }
        let active = mac
            .mask()
            .filter(|m| m.active_count() < m.as_slice().len())
            .map(|m| m.as_slice().to_vec());
        Level::from_faces(
            (nx, ny),
            (grid.boundary_x, grid.boundary_y),
            fx,
            fy,
            wall,
            [vec![1.0; nx], vec![1.0; ny]],
            active,
        )
    }

    /// The next coarser level (see the module docs): a coupling or wall term
    /// scales with the distance it spans, `a_c = Σ a_f (d_f / d_c) / 4`
    /// (`d` the distance between the two cell centres, or from the centre to
    /// the wall; `/4` the area of a merged cell), which is `Σ a_f / 8` where
    /// both cells have two children along the axis.
    pub(super) fn coarsen(&self) -> Self {
        let (nx, ny) = (self.nx, self.ny);
        let (cnx, cny) = (nx.div_ceil(2), ny.div_ceil(2));
        let merge = |w: &[f64]| -> Vec<f64> { w.chunks(2).map(|c| c.iter().sum()).collect() };
        let (wx, wy) = (&self.widths[0], &self.widths[1]);
        let (cwx, cwy) = (merge(wx), merge(wy));
        let mut fx = vec![0.0; cnx * cny];
        let mut fy = vec![0.0; cnx * cny];
        let mut wall = [vec![0.0; cnx * cny], vec![0.0; cnx * cny]];
        // A coarse cell is active if any of its children is: the coarse grids
        // cover all the fluid, up to the obstacle, and their couplings are
        // the sums of the open fine faces between their children (a cut cell
        // has fewer). Only a cell wholly inside an obstacle gets no
        // correction. (Active only where all children were left a band of
        // 2^l fine cells around each obstacle to the smoother on level l,
        // and the iterations grew with the grid: 15-25 at 64^2-128^2 with
        // a cylinder or a box, against 8-10 now.)
        let mut active = vec![false; cnx * cny];
        for k in 0..nx * ny {
            if self.is_active(k) {
                active[(k / ny / 2) * cny + (k % ny) / 2] = true;
            }
        }
        for i in 0..nx {
            for j in 0..ny {
                let k = i * ny + j;
                let (ci, cj) = (i / 2, j / 2);
                let parent = ci * cny + cj;
                if !self.is_active(k) {
                    continue;
                }
                let east = if i + 1 < nx { i + 1 } else { 0 };
                let north = if j + 1 < ny { j + 1 } else { 0 };
                let east_parent = (east / 2) * cny + cj;
                let north_parent = ci * cny + north / 2;
                let x_ratio = (wx[i] + wx[east]) / (cwx[ci] + cwx[east / 2]) / 4.0;
                let y_ratio = (wy[j] + wy[north]) / (cwy[cj] + cwy[north / 2]) / 4.0;
                let cross_x = self.fx[k] != 0.0 && east / 2 != ci;
                let cross_y = self.fy[k] != 0.0 && north / 2 != cj;
                // `k` is active, so its parent is; a coupling joins two
                // active cells (an open face), so the neighbour's parent is
                // active too.
                wall[0][parent] += self.wall[0][k] * wx[i] / cwx[ci] / 4.0;
                wall[1][parent] += self.wall[1][k] * wy[j] / cwy[cj] / 4.0;
                if cross_x {
                    debug_assert!(active[east_parent], "a coupling to an inactive cell");
                    fx[parent] += self.fx[k] * x_ratio;
                }
                if cross_y {
                    debug_assert!(active[north_parent], "a coupling to an inactive cell");
                    fy[parent] += self.fy[k] * y_ratio;
                }
            }
        }
        let active = (self.active.is_some()).then_some(active);
        Level::from_faces(
            (cnx, cny),
            (self.bx, self.by),
            fx,
            fy,
            wall,
            [cwx, cwy],
            active,
        )
    }

    /// `Σ a x_neighbour` at `(i, j)`, in f64.
    #[inline]
    pub(super) fn off(&self, x: &[f64], i: usize, j: usize) -> f64 {
        // Zero couplings skipped: their index may be a far row (a wall's wrap).
        self.couplings(i, j)
            .iter()
            .filter(|&&(_, a)| a != 0.0)
            .map(|&(n, a)| a * x[n])
            .sum()
    }

    /// `r = b − A x` (used to build the coarsest matrix and in tests).
    pub(super) fn residual(&self, x: &[f64], b: &[f64], r: &mut [f64]) {
        for i in 0..self.nx {
            for j in 0..self.ny {
                let k = i * self.ny + j;
                let off = self.off(x, i, j);
                r[k] = b[k] - (self.diag[k] * x[k] - off);
            }
        }
    }
}

// These read the levels' private operators (couplings, diagonal, masks,
// residual), which no public item exposes.
#[cfg(test)]
mod tests {
    use super::super::Multigrid;
    use crate::mac::MacGrid;
    use crate::stencil::Laplacian2;
    use crate::{Boundary, Grid2, LinearOperator};
    use diffphys_tape::test_array;

    const KINDS: [Boundary; 3] = [
        Boundary::ZeroDirichlet,
        Boundary::Closed,
        Boundary::Periodic,
    ];

    fn grid(nx: usize, ny: usize, bx: Boundary, by: Boundary) -> Grid2 {
        let mut g = Grid2::new(nx, ny, 1.0 / nx as f64, 1.3 / ny as f64, bx).unwrap();
        g.boundary_y = by;
        g
    }

    #[test]
    fn the_level_operator_is_the_laplacian() {
        for bx in KINDS {
            for by in KINDS {
                let g = grid(8, 6, bx, by);
                let level = &Multigrid::new(&g, 1).unwrap().levels[0];
                let x = test_array::<f64>(&[8, 6], 1);
                let mut r = vec![0.0; 48];
                level.residual(x.as_slice().unwrap(), &[0.0; 48], &mut r);
                let a = LinearOperator::<f64>::apply(&Laplacian2::negative(g), x.view()).unwrap();
                for (p, q) in r.iter().zip(a.iter()) {
                    assert!((-p - q).abs() < 1e-9 * q.abs().max(1.0), "{bx:?} {by:?}");
                }
            }
        }
    }

    /// Staggered grids of every kind, with odd sizes and an obstacle.
    fn macs(nx: usize, ny: usize) -> Vec<(&'static str, MacGrid)> {
        use crate::CellMask;
        let g = |bx, by| grid(nx, ny, Boundary::Closed, Boundary::Closed).with_boundaries(bx, by);
        let obstacle = |g: &Grid2| {
            CellMask::from_fn2(g, |c| {
                let (x, y) = (c[0] - 0.45, c[1] - 0.6);
                x * x + y * y > 0.04 && !(c[0] > 0.7 && c[1] < 0.4)
            })
        };
        let (closed, open) = (
            g(Boundary::Closed, Boundary::Closed),
            g(Boundary::ZeroDirichlet, Boundary::Closed),
        );
        vec![
            ("closed", MacGrid::new(closed)),
            (
                "open",
                MacGrid::new(g(Boundary::ZeroDirichlet, Boundary::ZeroDirichlet)),
            ),
            (
                "periodic",
                MacGrid::new(g(Boundary::Periodic, Boundary::Periodic)),
            ),
            (
                "masked-closed",
                MacGrid::with_mask(closed, obstacle(&closed)).unwrap(),
            ),
            (
                "masked-open",
                MacGrid::with_mask(open, obstacle(&open)).unwrap(),
            ),
        ]
    }

    #[test]
    fn the_mac_level_operator_is_the_pressure_operator() {
        for (name, mac) in macs(11, 9) {
            let level = &Multigrid::for_mac(&mac, 1).unwrap().levels[0];
            let x = test_array::<f64>(&[11, 9], 1);
            let mut r = vec![0.0; 99];
            level.residual(x.as_slice().unwrap(), &[0.0; 99], &mut r);
            let a = LinearOperator::<f64>::apply(&mac.pressure_operator(), x.view()).unwrap();
            for (p, q) in r.iter().zip(a.iter()) {
                assert!((-p - q).abs() < 1e-9 * q.abs().max(1.0), "{name}");
            }
        }
    }

    #[test]
    fn coarse_levels_are_semidefinite_and_cover_every_fluid_cell() {
        for (name, mac) in macs(40, 27) {
            let mg = Multigrid::for_mac(&mac, 2).unwrap();
            assert!(mg.levels() >= 3, "{name}");
            for level in &mg.levels[1..] {
                // Each coupling is stored once, so symmetry holds by
                // construction; the diagonal dominates (semidefinite).
                for k in 0..level.cells() {
                    let (i, j) = (k / level.ny, k % level.ny);
                    let off: f64 = level.couplings(i, j).iter().map(|c| c.1).sum();
                    assert!(level.diag[k] >= off - 1e-12 * off.abs(), "{name}");
                }
            }
            // A coarse cell is active exactly when any of its children is;
            // some are cut by the obstacle (active, with an inactive child).
            if let Some(fine) = &mg.levels[0].active {
                let coarse = mg.levels[1].active.as_ref().unwrap();
                let cny = mg.levels[1].ny;
                let mut cut = 0;
                for (c, &a) in coarse.iter().enumerate() {
                    let (ci, cj) = (c / cny, c % cny);
                    let children: Vec<bool> = (2 * ci..(2 * ci + 2).min(40))
                        .flat_map(|i| (2 * cj..(2 * cj + 2).min(27)).map(move |j| (i, j)))
                        .map(|(i, j)| fine[i * 27 + j])
                        .collect();
                    assert_eq!(a, children.iter().any(|&f| f), "{name}: coarse cell {c}");
                    cut += usize::from(a && children.iter().any(|&f| !f));
                }
                assert!(cut > 0, "{name}: no coarse cell is cut by the obstacle");
            }
        }
    }
}
