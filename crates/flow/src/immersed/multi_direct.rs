//! Multi-direct forcing: the direct forcing and the pressure projection
//! alternated within the step, so that the step's velocity meets the wall
//! condition and the divergence constraint together, whatever the time step.
//!
//! The direct forcing ([`super::immersed_forcing`], `F`) sets the forced faces
//! before the projection `Π` (the velocity part of
//! [`crate::pressure::project`]), which then moves them by `τ G φ`. At a steady
//! state the forced faces are then off the interpolation by a slip that the
//! step itself creates, of order `dt`: the steady forces depend on the
//! Courant number (docs/10, "Where the lift error comes from"). Here the pair
//! is applied `K` times ([`ForcingScheme::MultiDirect`]'s `passes`):
//!
//! ```text
//! v₀ = u
//! w_k = F(v_k)                   the forced faces on the interpolation
//! (v_{k+1}, φ_k) = Π(w_k)        divergence-free again, the forced faces moved
//! u' = v_K,  P = Σ_k φ_k         the pressure that acted on the free faces
//! ```
//!
//! `Π∘F` moves only the velocity's distance from the set of fields that are
//! divergence-free *and* on the interpolation, and shrinks it by a fixed
//! factor `ρ < 1` a pass (alternating projections): after `K` passes the slip
//! left is `ρ^(K−1)` times the direct forcing's, so the step's dependence on
//! `dt` through the slip falls by that factor; `K → ∞` is the velocity that
//! satisfies both constraints, the solution of the immersed boundary
//! projection method of Taira and Colonius (2007), which does not depend on
//! `τ`. `K = 1` is the direct forcing followed by the projection, bit for
//! bit. The output stays divergence-free (the last operation is `Π`), unlike
//! a forcing after the projection, which meets the wall condition exactly
//! but leaves a divergence of the slip's size in the cut cells for the next
//! step's advection to read. The state's pressure is the sum of the passes'
//! (`u' = u − τ G P` on every free face the forcing does not set), so the
//! incremental splitting's `−(dt/2) G Pⁿ` removes what the step added.
//!
//! **Force.** Each pass's forcing changes the momentum of the faces; their
//! sum over the passes is the momentum exchange with the body
//! ([`super::ForcingImpulse`], [`crate::StepInfo::immersed_force`]): the
//! projections in between move momentum only through the domain's open
//! sides.
//!
//! **Adjoint.** The map is linear in `u` at a fixed circle. With `ḡ_u`,
//! `ḡ_P` the gradients of `u'` and `P`, `F*` the VJP of the forcing
//! ([`super::immersed_forcing_vjp`], at `v_k`) and `Π*` that of the
//! projection ([`crate::pressure::project_vjp`], one solve), backwards over
//! the passes:
//!
//! ```text
//! a_K = ḡ_u
//! b_k = Π*(a_{k+1}, ḡ_P)          every pass's pressure gets ḡ_P
//! (a_k, θ̄_k) = F*(b_k) at v_k     θ̄_k the shape gradient of pass k
//! ∂L/∂u = a_0,  ∂L/∂θ = Σ_k θ̄_k
//! ```
//!
//! The op keeps nothing beyond its inputs: the backward reruns the `K − 1`
//! forward passes for the `v_k` the shape gradient reads (`K − 1` solves).
//!
//! # References
//! Z. Wang, J. Fan, K. Luo, *Combined multi-direct forcing and immersed
//! boundary method for simulating flows with moving particles*, Int. J.
//! Multiphase Flow 34 (2008) 283–302 (the forcing repeated within the step
//! until the boundary condition holds); K. Taira, T. Colonius, *The immersed
//! boundary method: a projection approach*, J. Comput. Phys. 225 (2007)
//! 2118–2137 (the no-slip and the divergence constraints solved together,
//! the limit of the passes); E. A. Fadlun et al. (2000), see [the module](super).

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2};

use std::sync::Arc;

use super::{
    immersed_forcing, immersed_forcing_vjp, ForcingImpulse, ForcingScheme, ImmersedCircle,
};
use crate::boundaries::{view1, view2};
use crate::pressure::{project, project_vjp, PressureSystem, SolveCounter};
use crate::{FlowError, Result};

const NAME: &str = "multi-direct immersed forcing";

/// What [`multi_direct_forcing`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct MultiDirect<T> {
    /// `u'_x`.
    pub ux: Array2<T>,
    /// `u'_y`.
    pub uy: Array2<T>,
    /// `P = Σ_k φ_k`, the pressure of the passes' projections summed.
    pub pressure: Array2<T>,
    /// The CG iterations of each pass's solve (0 for a direct solver).
    pub iterations: Vec<usize>,
    /// The momentum the passes' forcing added to the faces, `[x, y]`
    /// ([`ImmersedCircle::momentum_change`] summed over the passes).
    pub impulse: [f64; 2],
}

/// The passes run forward; with `keep`, the velocity `v_k` each pass's forcing read.
struct Sweep<T> {
    out: MultiDirect<T>,
    read: Vec<(Array2<T>, Array2<T>)>,
}

#[allow(clippy::too_many_arguments)]
fn sweep<T: Real>(
    body: &ImmersedCircle,
    system: &PressureSystem,
    tau: f64,
    passes: usize,
    (ux, uy): (ArrayView2<'_, T>, ArrayView2<'_, T>),
    guess: Option<ArrayView2<'_, T>>,
    shape: ArrayView1<'_, T>,
    keep: bool,
) -> Result<Sweep<T>> {
    if passes == 0 {
        return Err(FlowError::parameter(
            NAME,
            "passes",
            "need at least one pass of forcing and projection",
        ));
    }
    let mut v = (ux.to_owned(), uy.to_owned());
    let mut pressure: Option<Array2<T>> = None;
    let mut iterations = Vec::with_capacity(passes);
    let mut impulse = [0.0; 2];
    let mut read = Vec::new();
    for k in 0..passes {
        if keep {
            read.push(v.clone());
        }
        let w = immersed_forcing(body, v.0.view(), v.1.view(), shape)?;
        let m = body.momentum_change((v.0.view(), v.1.view()), (w.0.view(), w.1.view()));
        impulse = [impulse[0] + m[0], impulse[1] + m[1]];
        // later passes correct a small divergence: no guess
        let g = if k == 0 { guess } else { None };
        let p = project(system, tau, w.0.view(), w.1.view(), g)?;
        iterations.push(p.iterations);
        pressure = Some(match pressure {
            Some(mut total) => {
                total += &p.pressure;
                total
            }
            None => p.pressure,
        });
        v = (p.ux, p.uy);
    }
    Ok(Sweep {
        out: MultiDirect {
            ux: v.0,
            uy: v.1,
            pressure: pressure.expect("at least one pass"),
            iterations,
            impulse,
        },
        read,
    })
}

/// `K = passes` passes of the direct forcing `F` of `body` and the projection
/// `Π` of `system` over `τ`; the first solve starts from `guess` where the
/// solver iterates:
///
/// ```text
/// v₀ = u,  w_k = F(v_k),  (v_{k+1}, φ_k) = Π(w_k),  u' = v_K,  P = Σ_k φ_k
/// ```
///
/// Each pass shrinks the slip `u' − F(u')` the projection leaves on the
/// forced faces; one pass is the direct forcing followed by the projection
/// (see [`ForcingScheme::MultiDirect`]). References: Wang, Fan and Luo, Int.
/// J. Multiphase Flow 34 (2008) 283–302; Taira and Colonius, J. Comput.
/// Phys. 225 (2007) 2118–2137.
///
/// # Errors
/// [`FlowError::InvalidParameter`] for no pass; those of
/// [`super::immersed_forcing`] and [`crate::pressure::project`].
#[allow(clippy::too_many_arguments)]
pub fn multi_direct_forcing<T: Real>(
    body: &ImmersedCircle,
    system: &PressureSystem,
    tau: f64,
    passes: usize,
    u: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    guess: Option<ArrayView2<'_, T>>,
    shape: ArrayView1<'_, T>,
) -> Result<MultiDirect<T>> {
    Ok(sweep(body, system, tau, passes, u, guess, shape, false)?.out)
}

/// The vector–Jacobian product of [`multi_direct_forcing`]: `(∂L/∂u_x,
/// ∂L/∂u_y, ∂L/∂shape)` given the gradients `ḡ_u` of `u'` and `ḡ_P`
/// (absent: zero) of `P`, backwards over the passes with `F*` the VJP of
/// the forcing at `v_k` ([`super::immersed_forcing_vjp`]) and `Π*` that of
/// the projection ([`crate::pressure::project_vjp`]):
///
/// ```text
/// a_K = ḡ_u,  b_k = Π*(a_{k+1}, ḡ_P),  (a_k, θ̄_k) = F*(b_k),
/// ∂L/∂u = a_0,  ∂L/∂θ = Σ_k θ̄_k
/// ```
///
/// It reruns the `K − 1` forward passes for the `v_k`, then one solve a pass.
///
/// # Errors
/// As [`multi_direct_forcing`].
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn multi_direct_forcing_vjp<T: Real>(
    body: &ImmersedCircle,
    system: &PressureSystem,
    tau: f64,
    passes: usize,
    u: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    shape: ArrayView1<'_, T>,
    (gx, gy): (ArrayView2<'_, T>, ArrayView2<'_, T>),
    grad_pressure: Option<ArrayView2<'_, T>>,
) -> Result<(Array2<T>, Array2<T>, Array1<T>)> {
    body.grid().check_velocity(NAME, gx, gy)?;
    let Sweep { read, .. } = sweep(body, system, tau, passes, u, None, shape, true)?;
    let mut a = (gx.to_owned(), gy.to_owned());
    let mut g_shape = Array1::<T>::zeros(3);
    for v in read.iter().rev() {
        let b = project_vjp(system, tau, a.0.view(), a.1.view(), grad_pressure)?;
        let (ax, ay, s) =
            immersed_forcing_vjp(body, v.0.view(), v.1.view(), shape, b.0.view(), b.1.view())?;
        g_shape += &s;
        a = (ax, ay);
    }
    Ok((a.0, a.1, g_shape))
}

/// [`multi_direct_forcing`] as a tape op, in place of the forcing and the
/// projection: inputs `[u_x, u_y, pressure_guess, shape]`, outputs
/// `[u_x', u_y', P]`. The guess gets no gradient (as for
/// [`crate::pressure::Project`]); it keeps nothing beyond its inputs; each
/// forward adds the momentum its passes changed to
/// [`MultiDirectForcing::impulse`] and their solves to
/// [`MultiDirectForcing::counter`].
#[derive(Debug, Clone)]
pub struct MultiDirectForcing {
    /// The body and its forced faces.
    pub body: Arc<ImmersedCircle>,
    /// The pressure system of the projection.
    pub system: Arc<PressureSystem>,
    /// The projection's time scale `τ`.
    pub tau: f64,
    /// `K`, the passes of forcing and projection.
    pub passes: usize,
    /// Where the forwards' momentum changes go.
    pub impulse: ForcingImpulse,
    /// Where the forward solves' iteration counts go.
    pub counter: SolveCounter,
}

impl MultiDirectForcing {
    /// The passes of `scheme`: `K` for [`ForcingScheme::MultiDirect`], 1
    /// (the direct forcing, then the projection) for the others.
    pub fn passes_of(scheme: ForcingScheme) -> usize {
        match scheme {
            ForcingScheme::MultiDirect { passes } => passes as usize,
            _ => 1,
        }
    }
}

impl<T: Real> Op<T> for MultiDirectForcing {
    fn name(&self) -> &str {
        NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(NAME, 4, inputs.len())?;
        let out = multi_direct_forcing(
            &self.body,
            &self.system,
            self.tau,
            self.passes,
            (view2(&inputs[0])?, view2(&inputs[1])?),
            Some(view2(&inputs[2])?),
            view1(&inputs[3])?,
        )?;
        self.impulse.add(out.impulse);
        out.iterations.iter().for_each(|&n| self.counter.push(n));
        Ok(vec![
            out.ux.into_dyn(),
            out.uy.into_dyn(),
            out.pressure.into_dyn(),
        ])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        if !args.needs(0) && !args.needs(1) && !args.needs(3) {
            return Ok(vec![None; 4]);
        }
        let (gx, gy) = (args.grad_output_or_zeros(0), args.grad_output_or_zeros(1));
        let gp = args.grad_outputs[2].as_ref().map(view2).transpose()?;
        let (jx, jy, js) = multi_direct_forcing_vjp(
            &self.body,
            &self.system,
            self.tau,
            self.passes,
            (view2(args.input(0))?, view2(args.input(1))?),
            view1(args.input(3))?,
            (view2(&gx.view())?, view2(&gy.view())?),
            gp,
        )?;
        Ok(vec![
            args.needs(0).then(|| jx.into_dyn()),
            args.needs(1).then(|| jy.into_dyn()),
            None,
            args.needs(3).then(|| js.into_dyn()),
        ])
    }
}
