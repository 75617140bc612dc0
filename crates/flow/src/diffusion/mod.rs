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
use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2, IxDyn};

use std::sync::Arc;

use crate::boundaries::{scalar_of, view1, view2, Faces};
use crate::buffers::{copied, give_back, join, narrow, owned, walls_of, wide};
use crate::grid::{FlowGrid, Lattice};
use crate::spectral::PeriodicPoisson;

mod laplacian;

use crate::{FlowError, Result};
use laplacian::{ComponentLaplacian, Helmholtz, VectorLaplacian};

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
