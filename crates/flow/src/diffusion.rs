//! Viscosity: the vector Laplacian of the staggered velocity with the side
//! conditions, stepped explicitly or implicitly.
//!
//! Per component, on its free faces, the five-point Laplacian reads its
//! neighbours; beyond a side it reads the tangential ghost (`−u`, `u` or
//! `2U − u`, see [`crate::boundaries`]) or, along the normal, repeats the face
//! (zero gradient at an outflow). Fixed faces (walls, inflow, obstacle) are
//! read as they are. So the Laplacian is affine: `L u = L₀ u + c(U)`, with `L₀`
//! assembled once per grid and `c` linear in the wall speeds.
//!
//! ```text
//! explicit:  u' = u + ν dt L u                       (free faces)
//! implicit:  (I − ν dt L_FF) u'_F = u_F + ν dt (L_FX u_X + c(U))
//! ```
//!
//! `L_FF` (free faces to free faces) is symmetric negative semidefinite, so the
//! implicit operator `M = I − ν dt L_FF` is symmetric positive definite and the
//! solve is conjugate gradient (Jacobi-preconditioned; `M` is close to `I`);
//! on a box periodic in both axes without obstacle `M` is circulant and the
//! solve is the exact one of the fast Fourier transform (`crate::spectral`).
//!
//! **Adjoints.** Explicit: `∂L/∂u = g + ν dt L₀ᵀ g_F`, `∂L/∂ν = dt ⟨g_F, L u⟩`,
//! `∂L/∂U = ν dt ∂c/∂Uᵀ g_F`. Implicit, through the same solve path as the
//! pressure: `s = M⁻¹ g_F` (one more solve, `M` symmetric), then
//! `∂L/∂u_F = s`, `∂L/∂u_X = g_X + ν dt L_FXᵀ s`, `∂L/∂U = ν dt ∂c/∂Uᵀ s` and
//! `∂L/∂ν = dt ⟨s, (L u')_F⟩` (from `∂M/∂ν u' = −dt L_FF u'`).
//!
//! The explicit step and the adjoints apply `L` in face indices: a free face
//! whose four lattice neighbours are all there (away from the non-periodic
//! sides) has the plain five-point row, computed as a stencil (its fixed
//! neighbours read with the same coefficient as free ones); the rows beside
//! the sides (ghosts, zero gradient) are a small sparse matrix. `L_FF` itself
//! stays assembled for the implicit operator.
//!
//! Explicit diffusion is stable for `ν dt (1/dx² + 1/dy²) ≤ ½`
//! ([`explicit_diffusion_number`]); the step checks it.

use diffphys_ops::cg::{conjugate_gradient, CgParams, Preconditioning};
use diffphys_ops::LinearOperator;
use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2, ArrayViewMutD, IxDyn};

use std::sync::Arc;

use crate::boundaries::{scalar_of, view1, view2, FaceKind, Faces};
use crate::buffers::{
    copied, for_row_blocks, give_back, join, narrow, owned, scratch, walls_of, wide, zeros,
};
use crate::grid::{FlowGrid, Lattice};
use crate::sparse::Csr;
use crate::spectral::PeriodicPoisson;
use crate::{FlowError, Result};

/// How viscosity is stepped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViscosityMode {
    /// Forward Euler; stable for `ν dt (1/dx² + 1/dy²) ≤ ½`.
    Explicit,
    /// Backward Euler, a Helmholtz solve per component.
    Implicit,
}

/// The viscous operator of a grid with its faces, assembled once: the vector
/// Laplacian with the side conditions, the Fourier solves of a periodic box,
/// and the conjugate gradient of the implicit step. What [`diffuse`] steps.
#[derive(Debug, Clone)]
pub struct Diffusion {
    grid: FlowGrid,
    laplacian: VectorLaplacian,
    /// The Fourier solves of a box periodic in both axes without obstacle.
    spectral: Option<Arc<PeriodicPoisson>>,
    /// The implicit step's solve.
    solver: CgParams,
}

impl Diffusion {
    /// Assembles the Laplacian of `grid` with its `faces`; `solver` is the
    /// implicit step's CG (where the transform does not solve it).
    pub fn new(grid: &FlowGrid, faces: &Faces, solver: CgParams) -> Self {
        let spectral = PeriodicPoisson::for_grid(grid, faces).map(Arc::new);
        Self::with_spectral(grid, faces, solver, spectral)
    }

    /// [`Diffusion::new`] sharing the Fourier solves of a periodic box.
    pub(crate) fn with_spectral(
        grid: &FlowGrid,
        faces: &Faces,
        solver: CgParams,
        spectral: Option<Arc<PeriodicPoisson>>,
    ) -> Self {
        Diffusion {
            grid: grid.clone(),
            laplacian: VectorLaplacian::new(grid, faces),
            spectral,
            solver,
        }
    }

    /// The grid.
    pub fn grid(&self) -> &FlowGrid {
        &self.grid
    }

    /// The Laplacians of both components.
    #[cfg(test)]
    pub(crate) fn laplacian(&self) -> &VectorLaplacian {
        &self.laplacian
    }
}

/// The Laplacian of one velocity component, split by the kind of column.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ComponentLaplacian {
    /// Rows and columns over the free faces (`L_FF`).
    ff: Csr,
    /// Rows over free faces, columns over all faces, only fixed columns (`L_FX`).
    fx: Csr,
    /// `(free row, side, coefficient)`: the wall terms `c(U)`.
    walls: Vec<(usize, usize, f64)>,
    /// The face of each free unknown.
    free: Vec<usize>,
    /// Faces of the component.
    len: usize,
    /// The component's lattice `[na, nb]` and the coefficients `(1/dx², 1/dy²)`.
    shape: [usize; 2],
    coeff: (f64, f64),
    /// `regular[k]`: the free face `k` reads its four lattice neighbours
    /// plainly (none missing, none itself, wrapping only along a periodic
    /// axis), so its row is the plain five-point stencil in face indices
    /// (fixed neighbours are read as they are, with the same coefficient).
    regular: Vec<bool>,
    /// The other free faces' rows in face indices (rows and columns over all
    /// faces): the ghost and zero-gradient rows beside the sides.
    edge: Csr,
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
    fn new(grid: &FlowGrid, lattice: Lattice, kinds: &[FaceKind]) -> Self {
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
        for (r, &k) in free.iter().enumerate() {
            let (a, b) = (k / nb, k % nb);
            let mut row = Vec::new();
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
                            let (factor, wall) = grid.sides.get(side).ghost();
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
                edge.extend(row);
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

    fn gather(&self, u: &[f64]) -> Vec<f64> {
        self.free.iter().map(|&k| u[k]).collect()
    }

    /// `(L u)_k` at every free face `k` of `u` (face indices), 0 at the
    /// fixed faces: the five-point stencil on the regular rows (on all cores
    /// for a large lattice), the edge rows and the wall terms beside.
    fn apply_faces(&self, u: &[f64], walls: &[f64; 4]) -> Vec<f64> {
        let mut out = zeros(self.len);
        self.stencil_add(u, Some(&self.regular), &mut out);
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
    fn stencil_add(&self, v: &[f64], mask: Option<&[bool]>, out: &mut [f64]) {
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
                for (b, ob) in o.iter_mut().enumerate() {
                    let bm = if b == 0 { nb - 1 } else { b - 1 };
                    let bp = if b + 1 == nb { 0 } else { b + 1 };
                    let s = cx * (below[b] + above[b]) + cy * (row[bm] + row[bp]) + centre * row[b];
                    if m.is_none_or(|m| m[b]) {
                        *ob += s;
                    }
                }
            }
        });
    }

    /// Adds `alpha · ∂(L u)/∂(u, U)ᵀ g` to the gradients, `g` in face indices
    /// (read at the free faces only): the transpose of [`Self::apply_faces`].
    fn apply_faces_vjp(
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
    fn apply(&self, u: &[f64], walls: &[f64; 4]) -> Vec<f64> {
        let lu = self.apply_faces(u, walls);
        self.gather(&lu)
    }

    /// `(L_FX u + c(U))_F`: what the fixed faces and walls add.
    fn boundary_terms(&self, u: &[f64], walls: &[f64; 4]) -> Vec<f64> {
        let mut out = vec![0.0; self.free.len()];
        self.fx.mul_add(1.0, u, &mut out);
        for &(r, s, c) in &self.walls {
            out[r] += c * walls[s];
        }
        out
    }

    /// Adds `alpha · ∂(L u)_F/∂(u, U)ᵀ g_F` to the gradients.
    fn apply_vjp(
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
struct Helmholtz<'a> {
    lap: &'a ComponentLaplacian,
    nu_dt: f64,
    shape: [usize; 1],
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

/// Solves `M x = r` from `guess`: by FFT on a box periodic in both axes
/// without obstacle (every face free, `M` circulant; exact), by CG otherwise.
fn helmholtz_solve(
    diffusion: &Diffusion,
    lap: &ComponentLaplacian,
    nu_dt: f64,
    r: Vec<f64>,
    guess: Vec<f64>,
) -> Result<Vec<f64>> {
    let n = r.len();
    if n == 0 {
        return Ok(r);
    }
    if let Some(fft) = &diffusion.spectral {
        if lap.free.len() == lap.len {
            crate::spectral::check_finite("viscosity solve", "right-hand side", &r)?;
            return Ok(fft.solve_helmholtz(&r, nu_dt));
        }
    }
    let params = &diffusion.solver;
    let op = Helmholtz {
        lap,
        nu_dt,
        shape: [n],
    };
    let b = ArrayD::from_shape_vec(IxDyn(&[n]), r).expect("1D");
    let mut x = ArrayD::from_shape_vec(IxDyn(&[n]), guess).expect("1D");
    conjugate_gradient(&op, b.view(), x.view_mut(), params).map_err(|source| FlowError::Solve {
        step: "viscosity solve".into(),
        quantity: "velocity".into(),
        source,
    })?;
    Ok(x.into_raw_vec_and_offset().0)
}

/// `ν dt (1/dx² + 1/dy²)`: explicit diffusion is stable up to ½.
pub fn explicit_diffusion_number(grid: &FlowGrid, nu: f64, dt: f64) -> f64 {
    nu * dt * (1.0 / (grid.dx * grid.dx) + 1.0 / (grid.dy * grid.dy))
}

/// The gradients of [`diffuse`].
#[derive(Debug, Clone, PartialEq)]
pub struct DiffusionGrads<T> {
    /// `∂L/∂u_x`.
    pub ux: Array2<T>,
    /// `∂L/∂u_y`.
    pub uy: Array2<T>,
    /// `∂L/∂ν`.
    pub viscosity: T,
    /// `∂L/∂U` of the four wall speeds.
    pub wall_speed: Array1<T>,
}

const NAME: &str = "diffusion";

fn check_nu(nu: f64) -> Result<()> {
    if nu.is_finite() && nu > 0.0 {
        Ok(())
    } else {
        Err(FlowError::parameter(
            NAME,
            "viscosity",
            format!("need a finite viscosity > 0, got {nu}"),
        ))
    }
}

/// One viscosity step over `dt` with viscosity `nu` (see the [module docs](self)).
///
/// # Errors
/// [`FlowError::Shape`] for wrong shapes, [`FlowError::InvalidParameter`] for
/// `ν ≤ 0`, [`FlowError::Solve`] if the implicit solve fails.
#[allow(clippy::too_many_arguments)]
pub fn diffuse<T: Real>(
    diffusion: &Diffusion,
    mode: ViscosityMode,
    dt: f64,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    nu: T,
    wall_speed: ArrayView1<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    let (grid, lap) = (&diffusion.grid, &diffusion.laplacian);
    grid.check_velocity(NAME, ux, uy)?;
    grid.check_walls(NAME, wall_speed)?;
    let nu = nu.as_f64();
    check_nu(nu)?;
    let walls = walls_of(wall_speed);
    // the two components are independent: on two threads
    let component = |lat: Lattice, u: ArrayView2<'_, T>| -> Result<Array2<T>> {
        let l = lap.of(lat);
        let u = match mode {
            ViscosityMode::Explicit => {
                // u + ν dt L u written over L u, which is 0 at the fixed
                // faces (so they keep u)
                let u = wide(u);
                let mut next = l.apply_faces(&u, &walls);
                for (n, &v) in next.iter_mut().zip(u.iter()) {
                    *n = v + nu * dt * *n;
                }
                next
            }
            ViscosityMode::Implicit => {
                let mut u = owned(wide(u));
                let uf = l.gather(&u);
                let mut r = l.boundary_terms(&u, &walls);
                r.iter_mut()
                    .zip(&uf)
                    .for_each(|(r, u)| *r = u + nu * dt * *r);
                let new_free = helmholtz_solve(diffusion, l, nu * dt, r, uf)?;
                for (&k, v) in l.free.iter().zip(new_free) {
                    u[k] = v;
                }
                u
            }
        };
        Ok(narrow::<T>(grid.shape(lat), u))
    };
    let (ux, uy) = join(
        || component(Lattice::FaceX, ux),
        || component(Lattice::FaceY, uy),
    );
    Ok((ux?, uy?))
}

/// The vector–Jacobian product of [`diffuse`]; `out_x`, `out_y` are its
/// outputs (the implicit adjoint needs them), `grad_x`, `grad_y` their
/// gradients.
///
/// # Errors
/// As [`diffuse`].
#[allow(clippy::too_many_arguments)]
pub fn diffuse_vjp<T: Real>(
    diffusion: &Diffusion,
    mode: ViscosityMode,
    dt: f64,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    nu: T,
    wall_speed: ArrayView1<'_, T>,
    out: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    grad: (ArrayView2<'_, T>, ArrayView2<'_, T>),
) -> Result<DiffusionGrads<T>> {
    let (grid, lap) = (&diffusion.grid, &diffusion.laplacian);
    grid.check_velocity(NAME, ux, uy)?;
    grid.check_velocity(NAME, out.0, out.1)?;
    grid.check_velocity(NAME, grad.0, grad.1)?;
    grid.check_walls(NAME, wall_speed)?;
    let nu = nu.as_f64();
    check_nu(nu)?;
    let walls = walls_of(wall_speed);
    // each component's gradient, wall and ν terms of its own, on two threads
    // and added after in a fixed order
    let component = |lat: Lattice,
                     u: ArrayView2<'_, T>,
                     o: ArrayView2<'_, T>,
                     g: ArrayView2<'_, T>|
     -> Result<(Array2<T>, [f64; 4], f64)> {
        let mut g_walls = [0.0; 4];
        let mut g_nu = 0.0;
        let l = lap.of(lat);
        let u = wide(u);
        let g = wide(g);
        // The identity part: every face's gradient passes through (the free
        // faces' as `g`, the fixed faces' unchanged), plus ν dt Lᵀ g_F.
        let mut gu = copied(&g);
        match mode {
            ViscosityMode::Explicit => {
                l.apply_faces_vjp(nu * dt, &g, &mut gu, &mut g_walls);
                let lu = l.apply_faces(&u, &walls);
                g_nu += dt * l.free.iter().map(|&k| g[k] * lu[k]).sum::<f64>();
                give_back(lu);
            }
            ViscosityMode::Implicit => {
                // free faces are replaced by the solve's adjoint
                for &k in &l.free {
                    gu[k] = 0.0;
                }
                let g_free = l.gather(&g);
                let s = helmholtz_solve(diffusion, l, nu * dt, g_free.clone(), g_free)?;
                for (&k, &sv) in l.free.iter().zip(&s) {
                    gu[k] += sv;
                }
                l.apply_vjp(nu * dt, &s, &mut gu, &mut g_walls, false);
                let lo = l.apply(&wide(o), &walls);
                g_nu += dt * s.iter().zip(&lo).map(|(a, b)| a * b).sum::<f64>();
            }
        }
        debug_assert_eq!(gu.len(), l.len);
        Ok((narrow::<T>(grid.shape(lat), gu), g_walls, g_nu))
    };
    let (x, y) = join(
        || component(Lattice::FaceX, ux, out.0, grad.0),
        || component(Lattice::FaceY, uy, out.1, grad.1),
    );
    let ((ux, walls_x, nu_x), (uy, walls_y, nu_y)) = (x?, y?);
    let g_walls: [f64; 4] = std::array::from_fn(|s| walls_x[s] + walls_y[s]);
    let g_nu = nu_x + nu_y;
    Ok(DiffusionGrads {
        ux,
        uy,
        viscosity: T::from_f64(g_nu),
        wall_speed: g_walls.iter().map(|&v| T::from_f64(v)).collect(),
    })
}

/// [`diffuse`] as a tape op: inputs `[u_x, u_y, ν (0-d), wall_speed]`, outputs
/// `[u_x', u_y']`.
#[derive(Debug, Clone)]
pub struct Diffuse {
    /// The viscous operator.
    pub diffusion: Arc<Diffusion>,
    /// Explicit or implicit.
    pub mode: ViscosityMode,
    /// The time step.
    pub dt: f64,
}

impl<T: Real> Op<T> for Diffuse {
    fn name(&self) -> &str {
        NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(NAME, 4, inputs.len())?;
        let (a, b) = diffuse(
            &self.diffusion,
            self.mode,
            self.dt,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
            scalar_of(&inputs[2], "viscosity")?,
            view1(&inputs[3])?,
        )?;
        Ok(vec![a.into_dyn(), b.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let gx = args.grad_output_or_zeros(0);
        let gy = args.grad_output_or_zeros(1);
        let g = diffuse_vjp(
            &self.diffusion,
            self.mode,
            self.dt,
            view2(args.input(0))?,
            view2(args.input(1))?,
            scalar_of(args.input(2), "viscosity")?,
            view1(args.input(3))?,
            (view2(args.output(0))?, view2(args.output(1))?),
            (view2(&gx.view())?, view2(&gy.view())?),
        )?;
        let nu_shape = args.input(2).shape().to_vec();
        Ok(vec![
            args.needs(0).then(|| g.ux.into_dyn()),
            args.needs(1).then(|| g.uy.into_dyn()),
            args.needs(2)
                .then(|| ArrayD::from_elem(IxDyn(&nu_shape), g.viscosity)),
            args.needs(3).then(|| g.wall_speed.into_dyn()),
        ])
    }
}

/// Used by tests: the default solver parameters of the implicit step.
pub(crate) fn default_viscosity_solver() -> CgParams {
    CgParams::default()
        .with_rel_tol(1e-10)
        .with_preconditioner(Preconditioning::Jacobi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boundaries::Obstacle;
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
                    left: Boundary::NoSlip,
                    right: Boundary::Outflow,
                    bottom: Boundary::MovingWall { speed: 0.5 },
                    top: Boundary::FreeSlip,
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
            left: Boundary::Periodic,
            right: Boundary::Periodic,
            bottom: Boundary::NoSlip,
            top: Boundary::MovingWall { speed: -0.3 },
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
