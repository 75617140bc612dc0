//! First-order upwind advection, `∂d/∂t + u·∇d = 0`, one forward Euler step.
//!
//! 1D, per cell `i` (the seed formula of the design):
//! `d'_i = d_i − dt·[u⁺_i (d_{i+1} − d_i) + u⁻_i (d_i − d_{i−1})]`,
//! `u⁺_i = min(u_i/dx, 0)`, `u⁻_i = max(u_i/dx, 0)`: a positive velocity takes the
//! backward difference, a negative one the forward difference. In 2D the same
//! update is applied along x with `u_x/dx` and along y with `u_y/dy`, summed
//! (unsplit).
//!
//! Beyond an edge a periodic axis wraps; zero Dirichlet reads a ghost of value 0;
//! closed walls read a ghost equal to the edge cell (zero gradient).
//!
//! Adjoint, with `g = ∂L/∂d'`, `p = dt·u⁺`, `m = dt·u⁻`:
//! `∂L/∂d_i = g_i (1 + p_i − m_i) − p_{i−1} g_{i−1} + m_{i+1} g_{i+1}` (ghost
//! relations mapped back through the boundary), and
//! `∂L/∂u_i = −(dt/dx)·g_i·[𝟙(u_i<0)(d_{i+1} − d_i) + 𝟙(u_i>0)(d_i − d_{i−1})]`,
//! taking the derivative of `min(u, 0)` and `max(u, 0)` as 0 at `u = 0` exactly.
//!
//! The step is stable for Courant numbers `C = dt·max_i |u_i|/dx ≤ 1` (2D:
//! `dt·max (|u_x|/dx + |u_y|/dy) ≤ 1`); above that the functions return
//! [`OpsError::Cfl`] unless [`AdvectionParams::allow_cfl_violation`] is set.
//!
//! # References
//! R. Courant, E. Isaacson, M. Rees, *On the solution of nonlinear hyperbolic
//! differential equations by finite differences*, Comm. Pure Appl. Math. 5 (1952).
//! R. J. LeVeque, *Finite Volume Methods for Hyperbolic Problems*, CUP 2002, §4.8.

use diffphys_tape::Real;
use ndarray::{Array1, Array2, Array3, ArrayView1, ArrayView2, ArrayView3, Ix1, Ix2, Ix3};

use super::{
    check_finite_velocity, check_shape, AdvectionGrads, AdvectionParams, AdvectionScheme,
    AdvectionVjp, Wants,
};
use crate::stencil::{edge_indices, next, prev, Ghost, Neighbour};
use crate::{Boundary, Grid1, Grid2, OpsError, Result};

/// The ghost rule of upwind advection for a boundary kind.
fn ghost(b: Boundary) -> Ghost {
    match b {
        Boundary::Periodic => Ghost::Wrap,
        Boundary::ZeroDirichlet => Ghost::Mirror(0.0),
        Boundary::Closed => Ghost::Mirror(1.0),
    }
}

/// `(p, m) = (a·min(u, 0), a·max(u, 0))`, the Courant numbers that multiply the
/// forward and the backward difference.
#[inline]
fn split<T: Real>(u: T, a: T) -> (T, T) {
    (a * u.min(T::zero()), a * u.max(T::zero()))
}

/// `(∂p/∂u, ∂m/∂u)`, zero at `u = 0`.
#[inline]
fn split_derivative<T: Real>(u: T, a: T) -> (T, T) {
    let z = T::zero();
    (if u < z { a } else { z }, if u > z { a } else { z })
}

fn value<T: Real>(d: &[T], n: Neighbour) -> T {
    T::from_f64(n.w) * d[n.idx]
}

/// Along one contiguous line: `out += −p (d⁺ − d) − m (d − d⁻)`.
fn line_forward<T: Real>(d: &[T], u: &[T], out: &mut [T], a: T, ghost: Ghost) {
    let n = d.len();
    for j in edge_indices(n) {
        let (l, r) = (prev(j, n, ghost), next(j, n, ghost));
        let (p, m) = split(u[j], a);
        out[j] -= p * (value(d, r) - d[j]) + m * (d[j] - value(d, l));
    }
    if n > 2 {
        for ((o, w), &uj) in out[1..n - 1].iter_mut().zip(d.windows(3)).zip(&u[1..n - 1]) {
            let (p, m) = split(uj, a);
            *o -= p * (w[2] - w[1]) + m * (w[1] - w[0]);
        }
    }
}

/// Along one line: `gd += (∂ line_forward/∂d)ᵀ g`, the identity term excluded.
fn line_vjp_field<T: Real>(g: &[T], u: &[T], gd: &mut [T], a: T, ghost: Ghost) {
    let n = g.len();
    for ((o, &gj), &uj) in gd.iter_mut().zip(g).zip(u) {
        let (p, m) = split(uj, a);
        *o += (p - m) * gj;
    }
    // Interior relations: cell j reads d_{j+1} with −p_j and d_{j−1} with +m_j.
    for ((o, &gj), &uj) in gd[1..].iter_mut().zip(g).zip(u) {
        *o -= split(uj, a).0 * gj;
    }
    for ((o, &gj), &uj) in gd.iter_mut().zip(&g[1..]).zip(&u[1..]) {
        *o += split(uj, a).1 * gj;
    }
    // The relations across the two edges.
    let l = prev(0, n, ghost);
    gd[l.idx] += T::from_f64(l.w) * split(u[0], a).1 * g[0];
    let r = next(n - 1, n, ghost);
    gd[r.idx] -= T::from_f64(r.w) * split(u[n - 1], a).0 * g[n - 1];
}

/// Along one line: `gu += (∂ line_forward/∂u)ᵀ g`.
fn line_vjp_velocity<T: Real>(d: &[T], u: &[T], g: &[T], gu: &mut [T], a: T, ghost: Ghost) {
    let n = d.len();
    for j in edge_indices(n) {
        let (l, r) = (prev(j, n, ghost), next(j, n, ghost));
        let (dp, dm) = split_derivative(u[j], a);
        gu[j] -= g[j] * (dp * (value(d, r) - d[j]) + dm * (d[j] - value(d, l)));
    }
    if n > 2 {
        let inner = gu[1..n - 1].iter_mut().zip(d.windows(3));
        for ((o, w), (&uj, &gj)) in inner.zip(u[1..n - 1].iter().zip(&g[1..n - 1])) {
            let (dp, dm) = split_derivative(uj, a);
            *o -= gj * (dp * (w[2] - w[1]) + dm * (w[1] - w[0]));
        }
    }
}

/// Across rows of a 2D field: `out += −p (wq·dq − dc) − m (dc − wp·dp)` where
/// `dp`, `dq` are the rows before and after `dc` (with their ghost weights).
#[allow(clippy::too_many_arguments)]
fn rows_forward<T: Real>(
    dc: &[T],
    dp: &[T],
    dq: &[T],
    (wp, wq): (T, T),
    u: &[T],
    out: &mut [T],
    a: T,
) {
    let rows = dc.iter().zip(dp).zip(dq);
    for ((o, &uj), ((&c, &pv), &qv)) in out.iter_mut().zip(u).zip(rows) {
        let (p, m) = split(uj, a);
        *o -= p * (wq * qv - c) + m * (c - wp * pv);
    }
}

#[allow(clippy::too_many_arguments)]
fn rows_vjp_velocity<T: Real>(
    dc: &[T],
    dp: &[T],
    dq: &[T],
    (wp, wq): (T, T),
    u: &[T],
    g: &[T],
    gu: &mut [T],
    a: T,
) {
    let rows = dc.iter().zip(dp).zip(dq);
    for (((o, &uj), &gj), ((&c, &pv), &qv)) in gu.iter_mut().zip(u).zip(g).zip(rows) {
        let (dpu, dmu) = split_derivative(uj, a);
        *o -= gj * (dpu * (wq * qv - c) + dmu * (c - wp * pv));
    }
}

/// `max_i |u_i|·a` over a slice, with the velocity checked for NaN and infinity.
fn courant_1d<T: Real>(op: &str, u: &[T], a: f64) -> Result<f64> {
    check_finite_velocity(op, u)?;
    Ok(u.iter().fold(0.0f64, |c, v| c.max(v.as_f64().abs())) * a)
}

fn check_courant(op: &str, courant: f64, params: &AdvectionParams) -> Result<()> {
    if courant > 1.0 && !params.allow_cfl_violation {
        return Err(OpsError::Cfl {
            op: op.to_string(),
            courant,
            limit: 1.0,
        });
    }
    Ok(())
}

const OP_1D: &str = "upwind_1d";
const OP_2D: &str = "upwind_2d";

/// One upwind step of the field `d` by the velocity `u` on a 1D grid (both of
/// shape `[n]`); see the [module docs](self) for the formula and its adjoint.
///
/// # Errors
/// [`OpsError::ShapeMismatch`] for wrong shapes, [`OpsError::InvalidArgument`]
/// for a non-positive `dt`, [`OpsError::NonFinite`] for a non-finite velocity and
/// [`OpsError::Cfl`] if `dt·max|u|/dx > 1` and violations are not allowed.
pub fn upwind1<T: Real>(
    grid: &Grid1,
    params: &AdvectionParams,
    d: ArrayView1<'_, T>,
    u: ArrayView1<'_, T>,
) -> Result<Array1<T>> {
    params.check_dt(OP_1D)?;
    check_shape(OP_1D, &grid.shape(), &d)?;
    check_shape(OP_1D, &grid.shape(), &u)?;
    let a = params.dt / grid.dx;
    let (d, u) = (d.as_standard_layout(), u.as_standard_layout());
    let (ds, us) = (
        d.as_slice().expect("standard"),
        u.as_slice().expect("standard"),
    );
    check_courant(OP_1D, courant_1d(OP_1D, us, a)?, params)?;
    let mut out = d.to_owned();
    let o = out.as_slice_mut().expect("owned arrays are standard");
    line_forward(ds, us, o, T::from_f64(a), ghost(grid.boundary));
    Ok(out)
}

/// The vector–Jacobian product of [`upwind1`]: given `g = ∂L/∂d'`, the
/// gradients `∂L/∂d` and `∂L/∂u` that `wants` asks for. Does not re-check the CFL
/// condition (the forward did).
///
/// # Errors
/// [`OpsError::ShapeMismatch`] for wrong shapes, [`OpsError::InvalidArgument`]
/// for a non-positive `dt`.
pub fn upwind1_vjp<T: Real>(
    grid: &Grid1,
    params: &AdvectionParams,
    d: ArrayView1<'_, T>,
    u: ArrayView1<'_, T>,
    grad_out: ArrayView1<'_, T>,
    wants: Wants,
) -> Result<AdvectionGrads<Array1<T>, Array1<T>>> {
    params.check_dt(OP_1D)?;
    for a in [&d, &u, &grad_out] {
        check_shape(OP_1D, &grid.shape(), a)?;
    }
    let a = T::from_f64(params.dt / grid.dx);
    let gh = ghost(grid.boundary);
    let (d, u, g) = (
        d.as_standard_layout(),
        u.as_standard_layout(),
        grad_out.as_standard_layout(),
    );
    let (ds, us, gs) = (
        d.as_slice().unwrap(),
        u.as_slice().unwrap(),
        g.as_slice().unwrap(),
    );
    let field = wants.field.then(|| {
        let mut gd = g.to_owned();
        line_vjp_field(gs, us, gd.as_slice_mut().unwrap(), a, gh);
        gd
    });
    let velocity = wants.velocity.then(|| {
        let mut gu = Array1::zeros(grid.n);
        line_vjp_velocity(ds, us, gs, gu.as_slice_mut().unwrap(), a, gh);
        gu
    });
    Ok(AdvectionGrads { field, velocity })
}

/// The rows of axis 0 before and after row `i`, with ghost weights.
fn row_neighbours<T: Real>(i: usize, n: usize, gh: Ghost) -> (usize, usize, (T, T)) {
    let (p, q) = (prev(i, n, gh), next(i, n, gh));
    (p.idx, q.idx, (T::from_f64(p.w), T::from_f64(q.w)))
}

/// One upwind step of the field `d` (shape `[nx, ny]`) by the velocity `u`
/// (shape `[2, nx, ny]`, components `[u_x, u_y]`) on a 2D grid: the 1D update
/// along each axis, summed. See the [module docs](self).
///
/// # Errors
/// As [`upwind1`], with the Courant number `dt·max(|u_x|/dx + |u_y|/dy)`.
pub fn upwind2<T: Real>(
    grid: &Grid2,
    params: &AdvectionParams,
    d: ArrayView2<'_, T>,
    u: ArrayView3<'_, T>,
) -> Result<Array2<T>> {
    params.check_dt(OP_2D)?;
    let (nx, ny) = (grid.nx, grid.ny);
    check_shape(OP_2D, &grid.shape(), &d)?;
    check_shape(OP_2D, &[2, nx, ny], &u)?;
    let (ax, ay) = (params.dt / grid.dx, params.dt / grid.dy);
    let (d, u) = (d.as_standard_layout(), u.as_standard_layout());
    let (ds, us) = (d.as_slice().unwrap(), u.as_slice().unwrap());
    check_finite_velocity(OP_2D, us)?;
    let (ux, uy) = us.split_at(nx * ny);
    let courant = ux.iter().zip(uy).fold(0.0f64, |c, (p, q)| {
        c.max(p.as_f64().abs() * ax + q.as_f64().abs() * ay)
    });
    check_courant(OP_2D, courant, params)?;
    let (gx, gy) = (ghost(grid.boundary_x), ghost(grid.boundary_y));
    let (axt, ayt) = (T::from_f64(ax), T::from_f64(ay));
    let mut out = d.to_owned();
    let o = out.as_slice_mut().unwrap();
    let line = |k: usize| k * ny..(k + 1) * ny;
    for i in 0..nx {
        let (p, q, w) = row_neighbours::<T>(i, nx, gx);
        let oi = &mut o[line(i)];
        let di = &ds[line(i)];
        rows_forward(di, &ds[line(p)], &ds[line(q)], w, &ux[line(i)], oi, axt);
        line_forward(di, &uy[line(i)], oi, ayt, gy);
    }
    Ok(out)
}

/// The vector–Jacobian product of [`upwind2`]: `∂L/∂d` (shape `[nx, ny]`) and
/// `∂L/∂u` (shape `[2, nx, ny]`) as `wants` asks.
///
/// # Errors
/// As [`upwind1_vjp`].
pub fn upwind2_vjp<T: Real>(
    grid: &Grid2,
    params: &AdvectionParams,
    d: ArrayView2<'_, T>,
    u: ArrayView3<'_, T>,
    grad_out: ArrayView2<'_, T>,
    wants: Wants,
) -> Result<AdvectionGrads<Array2<T>, Array3<T>>> {
    params.check_dt(OP_2D)?;
    let (nx, ny) = (grid.nx, grid.ny);
    check_shape(OP_2D, &grid.shape(), &d)?;
    check_shape(OP_2D, &grid.shape(), &grad_out)?;
    check_shape(OP_2D, &[2, nx, ny], &u)?;
    let (gx, gy) = (ghost(grid.boundary_x), ghost(grid.boundary_y));
    let axt = T::from_f64(params.dt / grid.dx);
    let ayt = T::from_f64(params.dt / grid.dy);
    let (d, u, g) = (
        d.as_standard_layout(),
        u.as_standard_layout(),
        grad_out.as_standard_layout(),
    );
    let (ds, us, gs) = (
        d.as_slice().unwrap(),
        u.as_slice().unwrap(),
        g.as_slice().unwrap(),
    );
    let (ux, uy) = us.split_at(nx * ny);
    let line = |k: usize| k * ny..(k + 1) * ny;

    let field = wants.field.then(|| {
        let mut gd = g.to_owned();
        let o = gd.as_slice_mut().unwrap();
        for i in 0..nx {
            let (p, q, (wp, wq)) = row_neighbours::<T>(i, nx, gx);
            let (gi, uxi) = (&gs[line(i)], &ux[line(i)]);
            // Along x: cell i reads row q with −p·wq, row p with +m·wp, itself with p − m.
            for ((o, &gj), &uj) in o[line(i)].iter_mut().zip(gi).zip(uxi) {
                let (pu, mu) = split(uj, axt);
                *o += (pu - mu) * gj;
            }
            for ((o, &gj), &uj) in o[line(q)].iter_mut().zip(gi).zip(uxi) {
                *o -= wq * split(uj, axt).0 * gj;
            }
            for ((o, &gj), &uj) in o[line(p)].iter_mut().zip(gi).zip(uxi) {
                *o += wp * split(uj, axt).1 * gj;
            }
            line_vjp_field(gi, &uy[line(i)], &mut o[line(i)], ayt, gy);
        }
        gd
    });

    let velocity = wants.velocity.then(|| {
        let mut gu = Array3::zeros((2, nx, ny));
        let (gux, guy) = gu.as_slice_mut().unwrap().split_at_mut(nx * ny);
        for i in 0..nx {
            let (p, q, w) = row_neighbours::<T>(i, nx, gx);
            let r = line(i);
            let (di, gi) = (&ds[r.clone()], &gs[r.clone()]);
            let (dp, dq) = (&ds[line(p)], &ds[line(q)]);
            rows_vjp_velocity(di, dp, dq, w, &ux[r.clone()], gi, &mut gux[r.clone()], axt);
            line_vjp_velocity(di, &uy[r.clone()], gi, &mut guy[r], ayt, gy);
        }
        gu
    });
    Ok(AdvectionGrads { field, velocity })
}

/// First-order upwind on a 1D grid (field and velocity `[n]`): an
/// [`AdvectionScheme`] and a tape op with inputs `[d, u]`
/// (`tape.apply(Upwind1::new(grid, params), &[d, u])`).
#[derive(Debug, Clone, Copy)]
pub struct Upwind1 {
    /// The grid.
    pub grid: Grid1,
    /// Time step and CFL policy.
    pub params: AdvectionParams,
}

impl Upwind1 {
    /// The scheme on `grid` with `params`.
    pub fn new(grid: Grid1, params: AdvectionParams) -> Self {
        Upwind1 { grid, params }
    }
}

impl<T: Real> AdvectionScheme<T> for Upwind1 {
    type Field = Ix1;
    type Velocity = Ix1;

    fn name(&self) -> &'static str {
        OP_1D
    }

    fn step(&self, d: ArrayView1<'_, T>, u: ArrayView1<'_, T>) -> Result<Array1<T>> {
        upwind1(&self.grid, &self.params, d, u)
    }

    fn vjp(
        &self,
        d: ArrayView1<'_, T>,
        u: ArrayView1<'_, T>,
        grad_out: ArrayView1<'_, T>,
        wants: Wants,
    ) -> AdvectionVjp<T, Ix1, Ix1> {
        upwind1_vjp(&self.grid, &self.params, d, u, grad_out, wants)
    }
}

/// First-order upwind on a 2D grid (field `[nx, ny]`, velocity `[2, nx, ny]`):
/// an [`AdvectionScheme`] and a tape op with inputs `[d, u]`.
#[derive(Debug, Clone, Copy)]
pub struct Upwind2 {
    /// The grid.
    pub grid: Grid2,
    /// Time step and CFL policy.
    pub params: AdvectionParams,
}

impl Upwind2 {
    /// The scheme on `grid` with `params`.
    pub fn new(grid: Grid2, params: AdvectionParams) -> Self {
        Upwind2 { grid, params }
    }
}

impl<T: Real> AdvectionScheme<T> for Upwind2 {
    type Field = Ix2;
    type Velocity = Ix3;

    fn name(&self) -> &'static str {
        OP_2D
    }

    fn step(&self, d: ArrayView2<'_, T>, u: ArrayView3<'_, T>) -> Result<Array2<T>> {
        upwind2(&self.grid, &self.params, d, u)
    }

    fn vjp(
        &self,
        d: ArrayView2<'_, T>,
        u: ArrayView3<'_, T>,
        grad_out: ArrayView2<'_, T>,
        wants: Wants,
    ) -> AdvectionVjp<T, Ix2, Ix3> {
        upwind2_vjp(&self.grid, &self.params, d, u, grad_out, wants)
    }
}
