//! The direct forcing made consistent with the projection: the forced faces
//! are set so that, after the projection, they land on the interpolation
//! instead of being moved off it by `τ ∇P`.
//!
//! The direct forcing ([`super::immersed_forcing`], `F`) sets the forced faces
//! before the projection, which then subtracts `τ G_F Pⁿ⁺¹` from every free
//! face: a forced face ends at `F(u)_f − τ (G_F Pⁿ⁺¹)_f`, off its target by
//! the pressure gradient across the forced layer. With the pressure `Pⁿ` of
//! the state as the predictor of `Pⁿ⁺¹`, the consistent forcing applies `F` to
//! the velocity the projection is expected to leave and adds the gradient back:
//!
//! ```text
//! g  = G_F Pⁿ                         the pressure gradient on the free faces
//! v  = u − τ g                        the predicted projected velocity
//! u' = F(v) + τ g   on the forced faces with links (next to the wall),
//! u' = F(v) = 0     on the forced faces without links (inside the circle),
//! u' = u            elsewhere
//! ```
//!
//! (`u' = F(u − τ g) + τ (1 − Z) g` on every face, `Z` the mask of the forced
//! faces without links, since `F` passes the unforced faces through). After
//! the projection a linked face is `F(v)_f + τ (G_F (Pⁿ − Pⁿ⁺¹))_f`: on its
//! target up to the pressure's change over one step, zero at a steady state.
//! The faces inside the circle stay forced to zero before the projection, as
//! in `F`: corrected as well, every face of a cell inside the body would be
//! set to `τ (G_F Pⁿ)_f`, which the projection reproduces for any pressure
//! there, and the body's inner pressure would be left to drift (measured: it
//! grows without bound on the DFG channel). With `Pⁿ = 0` it is `F`.
//!
//! **Adjoint.** With `ḡ` the gradient of `u'` and `F*` the adjoint of `F`
//! at the circle (its VJP [`super::immersed_forcing_vjp`], evaluated at `v`),
//!
//! ```text
//! ∂L/∂u = F*(ḡ)
//! ∂L/∂P = τ D_F (F*(ḡ) − (1 − Z) ḡ)    (G_Fᵀ = −D_F)
//! ∂L/∂θ = the shape gradient of F at v
//! ```
//!
//! The map is linear in `(u, P)` at a fixed circle.
//!
//! # References
//! M. Uhlmann, *An immersed boundary method with direct forcing for the
//! simulation of particulate flows*, J. Comput. Phys. 209 (2005) 448–476
//! (forcing with the predicted pressure gradient); E. A. Fadlun et al. (2000),
//! see [the module](super).

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2};

use std::sync::Arc;

use super::{immersed_forcing, immersed_forcing_vjp, ForcingImpulse, ImmersedCircle};
use crate::boundaries::{view1, view2, Faces};
use crate::buffers::{narrow, wide};
use crate::grid::FlowGrid;
use crate::staggered::{divergence_wide, gradient_wide};
use crate::Result;

const NAME: &str = "projection-consistent immersed forcing";

/// How the immersed circle's forced faces are set
/// ([`crate::SceneBuilder::immersed_scheme`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum ForcingScheme {
    /// The interpolation of the velocity as the step has it before the
    /// projection ([`super::immersed_forcing`], Fadlun et al. 2000): the
    /// projection then moves the forced faces by `τ ∇Pⁿ⁺¹`.
    #[default]
    Direct,
    /// The interpolation of the predicted projected velocity `u − τ ∇Pⁿ`, plus
    /// `τ ∇Pⁿ`, on the faces next to the wall ([`consistent_forcing`]): they
    /// land on their target after the projection, up to the pressure's change
    /// over the step.
    ProjectionConsistent,
    /// The direct forcing and the projection alternated `passes` times
    /// within the step ([`super::multi_direct_forcing`]; Wang, Fan and Luo
    /// 2008): the slip the projection leaves on the forced faces shrinks
    /// with each pass, and the steady state tends to one that meets the wall
    /// condition and the divergence constraint whatever the time step. One
    /// pass is [`ForcingScheme::Direct`]. Each pass costs a pressure solve.
    MultiDirect {
        /// Passes of forcing and projection, at least 1 (3 is a good start).
        passes: u32,
    },
}

/// The projection-consistent forcing `u' = F(u − τ G_F P) + τ G_F P` on the
/// forced faces of `body` next to the wall, zero on those inside it, `u`
/// elsewhere (see [`ForcingScheme::ProjectionConsistent`]); `P`
/// is the state's pressure, `τ` the projection's time scale, `faces` the
/// scene's (the free faces the gradient acts on).
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes; those of
/// [`super::Circle::from_shape`].
pub fn consistent_forcing<T: Real>(
    body: &ImmersedCircle,
    faces: &Faces,
    tau: f64,
    u: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    pressure: ArrayView2<'_, T>,
    shape: ArrayView1<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    let p = Prediction::new(body.grid(), faces, tau, u, pressure)?;
    let (fx, fy) = immersed_forcing(body, p.v.0.view(), p.v.1.view(), shape)?;
    let [(forced_x, sx), (forced_y, sy)] = body.components();
    let put = |forced: &[super::ForcedFace],
               shape: [usize; 2],
               u: ArrayView2<'_, T>,
               f: &Array2<T>,
               g: &[f64]| {
        let mut out = wide(u).into_owned();
        let f = wide(f.view());
        for ff in forced {
            out[ff.face] = f[ff.face]
                + if ff.links.is_empty() {
                    0.0
                } else {
                    tau * g[ff.face]
                };
        }
        narrow(shape, out)
    };
    Ok((
        put(forced_x, sx, u.0, &fx, &p.g.0),
        put(forced_y, sy, u.1, &fy, &p.g.1),
    ))
}

/// The pressure gradient `g = G_F P` on the free faces and the predicted
/// projected velocity `v = u − τ g`, computed once for the forward and the
/// VJP (which needs `v` for the shape gradient of `F`).
struct Prediction<T> {
    g: (Vec<f64>, Vec<f64>),
    v: (Array2<T>, Array2<T>),
}

impl<T: Real> Prediction<T> {
    fn new(
        grid: &FlowGrid,
        faces: &Faces,
        tau: f64,
        (ux, uy): (ArrayView2<'_, T>, ArrayView2<'_, T>),
        pressure: ArrayView2<'_, T>,
    ) -> Result<Self> {
        grid.check_velocity(NAME, ux, uy)?;
        grid.check_cells(NAME, "pressure", pressure)?;
        let g = gradient_wide(grid, Some(faces), &wide(pressure));
        // `u − τ g`, as `subtract_pressure_gradient` computes it (0 on fixed faces)
        let minus = |u: ArrayView2<'_, T>, g: &[f64], shape: [usize; 2]| {
            let mut v = wide(u).into_owned();
            v.iter_mut().zip(g).for_each(|(v, g)| *v -= tau * g);
            narrow(shape, v)
        };
        let v = (
            minus(ux, &g.0, grid.shape_x()),
            minus(uy, &g.1, grid.shape_y()),
        );
        Ok(Prediction { g, v })
    }
}

/// The vector–Jacobian product of [`consistent_forcing`]: `(∂L/∂u_x,
/// ∂L/∂u_y, ∂L/∂P, ∂L/∂shape)` given the gradients `(g_x, g_y)` of its outputs.
///
/// # Errors
/// As [`consistent_forcing`].
#[allow(clippy::type_complexity)]
pub fn consistent_forcing_vjp<T: Real>(
    body: &ImmersedCircle,
    faces: &Faces,
    tau: f64,
    u: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    pressure: ArrayView2<'_, T>,
    shape: ArrayView1<'_, T>,
    (gx, gy): (ArrayView2<'_, T>, ArrayView2<'_, T>),
) -> Result<(Array2<T>, Array2<T>, Array2<T>, Array1<T>)> {
    let grid = body.grid();
    let Prediction { v: (vx, vy), .. } = Prediction::new(grid, faces, tau, u, pressure)?;
    let (jx, jy, js) = immersed_forcing_vjp(body, vx.view(), vy.view(), shape, gx, gy)?;
    // τ D_F (F*(ḡ) − (1 − Z) ḡ), Z the forced faces without links
    let [(forced_x, _), (forced_y, _)] = body.components();
    let diff = |forced: &[super::ForcedFace], j: &Array2<T>, g: ArrayView2<'_, T>| -> Vec<f64> {
        let mut g = wide(g).into_owned();
        for ff in forced.iter().filter(|ff| ff.links.is_empty()) {
            g[ff.face] = 0.0;
        }
        wide(j.view()).iter().zip(&g).map(|(a, b)| a - b).collect()
    };
    let mut gp = divergence_wide(
        grid,
        Some(faces),
        &diff(forced_x, &jx, gx),
        &diff(forced_y, &jy, gy),
    );
    gp.iter_mut().for_each(|v| *v *= tau);
    Ok((jx, jy, narrow(grid.cell_shape(), gp), js))
}

/// [`consistent_forcing`] as a tape op: inputs `[u_x, u_y, P, shape]`,
/// outputs `[u_x', u_y']`. It keeps nothing beyond its inputs; each forward
/// adds the momentum it changed, `Σ_forced (u'_f − u_f) dx dy`, to
/// [`ConsistentForcing::impulse`].
#[derive(Debug, Clone)]
pub struct ConsistentForcing {
    /// The body and its forced faces.
    pub body: Arc<ImmersedCircle>,
    /// The scene's faces (the pressure gradient acts on the free ones).
    pub faces: Arc<Faces>,
    /// The projection's time scale `τ`.
    pub tau: f64,
    /// Where the forwards' momentum changes go.
    pub impulse: ForcingImpulse,
}

impl<T: Real> Op<T> for ConsistentForcing {
    fn name(&self) -> &str {
        NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(NAME, 4, inputs.len())?;
        let u = (view2(&inputs[0])?, view2(&inputs[1])?);
        let (ux, uy) = consistent_forcing(
            &self.body,
            &self.faces,
            self.tau,
            u,
            view2(&inputs[2])?,
            view1(&inputs[3])?,
        )?;
        self.impulse.record(&self.body, u, (ux.view(), uy.view()));
        Ok(vec![ux.into_dyn(), uy.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let (gx, gy) = (args.grad_output_or_zeros(0), args.grad_output_or_zeros(1));
        let (jx, jy, jp, js) = consistent_forcing_vjp(
            &self.body,
            &self.faces,
            self.tau,
            (view2(args.input(0))?, view2(args.input(1))?),
            view2(args.input(2))?,
            view1(args.input(3))?,
            (view2(&gx.view())?, view2(&gy.view())?),
        )?;
        Ok(vec![
            args.needs(0).then(|| jx.into_dyn()),
            args.needs(1).then(|| jy.into_dyn()),
            args.needs(2).then(|| jp.into_dyn()),
            args.needs(3).then(|| js.into_dyn()),
        ])
    }
}
