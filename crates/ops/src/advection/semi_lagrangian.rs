//! Semi-Lagrangian advection: trace each cell centre back along the velocity and
//! interpolate the field there.
//!
//! 1D, cell `i` at `x_i`: the departure point `x_i − u_i·dt` lies at fractional
//! index `s_i = i − u_i·dt/dx`; with `j = ⌊s_i⌋` and `f = s_i − j`,
//! `d'_i = (1 − f)·d_j + f·d_{j+1}` (linear interpolation). In 2D the departure
//! point is `(i − u_x·dt/dx, j − u_y·dt/dy)` and the interpolation bilinear.
//! Unconditionally stable: there is no CFL limit, a departure point may lie many
//! cells away.
//!
//! Samples beyond the edges: periodic axes wrap; closed walls clamp the index to
//! the edge cell (zero gradient, so a sample outside the cell centres takes the
//! edge value); zero Dirichlet reads 0 beyond the edges.
//!
//! Adjoint, with `g = ∂L/∂d'`: the field gradient scatters `g_i` back to the two
//! (2D: four) cells it was interpolated from with the same weights,
//! `∂L/∂d_j += (1 − f)·g_i`, `∂L/∂d_{j+1} += f·g_i`; the velocity gradient goes
//! through the interpolation weights, `∂L/∂u_i = −(dt/dx)·g_i·(d_{j+1} − d_j)`
//! (2D: the bilinear slope along each axis). The map is piecewise linear in `u`,
//! with kinks where a departure point crosses a cell centre; there the one-sided
//! derivative from the right is taken.
//!
//! # References
//! A. Staniforth, J. Côté, *Semi-Lagrangian integration schemes for atmospheric
//! models — a review*, Mon. Wea. Rev. 119 (1991). J. Stam, *Stable Fluids*,
//! SIGGRAPH 1999.

use diffphys_tape::Real;
use ndarray::{Array1, Array2, Array3, ArrayView1, ArrayView2, ArrayView3, Ix1, Ix2, Ix3};

use super::{
    check_dt, check_finite_velocity, check_shape, AdvectionGrads, AdvectionScheme, AdvectionVjp,
    Wants,
};
use crate::{Boundary, Grid1, Grid2, Result};

const OP_1D: &str = "semi_lagrangian_1d";
const OP_2D: &str = "semi_lagrangian_2d";

/// The cell that integer index `k` reads on an axis of `n` cells, and the factor
/// on its value (0 beyond a zero-Dirichlet edge).
#[inline]
fn resolve(k: i64, n: usize, b: Boundary) -> (usize, f64) {
    let last = n as i64 - 1;
    match b {
        Boundary::Periodic => (k.rem_euclid(n as i64) as usize, 1.0),
        Boundary::Closed => (k.clamp(0, last) as usize, 1.0),
        Boundary::ZeroDirichlet if (0..=last).contains(&k) => (k as usize, 1.0),
        Boundary::ZeroDirichlet => (0, 0.0),
    }
}

/// One axis of an interpolation: the two cells read, their boundary factors and
/// the fractional position `f` between them.
#[derive(Debug, Clone, Copy)]
struct Axis1 {
    idx: [usize; 2],
    w: [f64; 2],
    f: f64,
}

/// Locates the departure point `i − displacement` on an axis.
#[inline]
fn locate(i: usize, displacement: f64, n: usize, b: Boundary) -> Axis1 {
    let s = i as f64 - displacement;
    let j = s.floor();
    let f = s - j;
    let j = j as i64; // saturating; the velocity is finite
    let (i0, w0) = resolve(j, n, b);
    let (i1, w1) = resolve(j.saturating_add(1), n, b);
    Axis1 {
        idx: [i0, i1],
        w: [w0, w1],
        f,
    }
}

impl Axis1 {
    /// The interpolation weights of the two cells, boundary factors included.
    fn weights<T: Real>(&self) -> [T; 2] {
        [
            T::from_f64((1.0 - self.f) * self.w[0]),
            T::from_f64(self.f * self.w[1]),
        ]
    }

    /// The two values read, boundary factors included.
    fn values<T: Real>(&self, d: &[T]) -> [T; 2] {
        [
            T::from_f64(self.w[0]) * d[self.idx[0]],
            T::from_f64(self.w[1]) * d[self.idx[1]],
        ]
    }
}

/// One semi-Lagrangian step of the field `d` by the velocity `u` on a 1D grid
/// (both of shape `[n]`); see the [module docs](self).
///
/// # Errors
/// [`crate::OpsError::ShapeMismatch`] for wrong shapes,
/// [`crate::OpsError::InvalidArgument`] for a non-positive `dt`, and
/// [`crate::OpsError::NonFinite`] for a non-finite velocity.
pub fn semi_lagrangian1<T: Real>(
    grid: &Grid1,
    dt: f64,
    d: ArrayView1<'_, T>,
    u: ArrayView1<'_, T>,
) -> Result<Array1<T>> {
    check_dt(OP_1D, dt)?;
    check_shape(OP_1D, &grid.shape(), &d)?;
    check_shape(OP_1D, &grid.shape(), &u)?;
    let (d, u) = (d.as_standard_layout(), u.as_standard_layout());
    let (ds, us) = (d.as_slice().unwrap(), u.as_slice().unwrap());
    check_finite_velocity(OP_1D, us)?;
    let a = dt / grid.dx;
    let out = us
        .iter()
        .enumerate()
        .map(|(i, ui)| {
            let ax = locate(i, ui.as_f64() * a, grid.n, grid.boundary);
            let [w0, w1] = ax.weights::<T>();
            w0 * ds[ax.idx[0]] + w1 * ds[ax.idx[1]]
        })
        .collect::<Vec<T>>();
    Ok(Array1::from(out))
}

/// The vector–Jacobian product of [`semi_lagrangian1`]: `∂L/∂d` and `∂L/∂u` as
/// `wants` asks, given `g = ∂L/∂d'`.
///
/// # Errors
/// As [`semi_lagrangian1`].
pub fn semi_lagrangian1_vjp<T: Real>(
    grid: &Grid1,
    dt: f64,
    d: ArrayView1<'_, T>,
    u: ArrayView1<'_, T>,
    grad_out: ArrayView1<'_, T>,
    wants: Wants,
) -> Result<AdvectionGrads<Array1<T>, Array1<T>>> {
    check_dt(OP_1D, dt)?;
    for a in [&d, &u, &grad_out] {
        check_shape(OP_1D, &grid.shape(), a)?;
    }
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
    check_finite_velocity(OP_1D, us)?;
    let a = dt / grid.dx;
    let mut gd = wants.field.then(|| vec![T::zero(); grid.n]);
    let mut gu = wants.velocity.then(|| vec![T::zero(); grid.n]);
    let minus_a = T::from_f64(-a);
    for (i, (ui, &gi)) in us.iter().zip(gs).enumerate() {
        let ax = locate(i, ui.as_f64() * a, grid.n, grid.boundary);
        if let Some(gd) = gd.as_mut() {
            let [w0, w1] = ax.weights::<T>();
            gd[ax.idx[0]] += w0 * gi;
            gd[ax.idx[1]] += w1 * gi;
        }
        if let Some(gu) = gu.as_mut() {
            // ∂d'/∂s = v₁ − v₀ and ∂s/∂u = −dt/dx
            let [v0, v1] = ax.values(ds);
            gu[i] = minus_a * gi * (v1 - v0);
        }
    }
    Ok(AdvectionGrads {
        field: gd.map(Array1::from),
        velocity: gu.map(Array1::from),
    })
}

/// The bilinear sample of cell `(i, j)`'s departure point.
struct Sample2 {
    x: Axis1,
    y: Axis1,
}

impl Sample2 {
    fn at(grid: &Grid2, i: usize, j: usize, disp: (f64, f64)) -> Self {
        Sample2 {
            x: locate(i, disp.0, grid.nx, grid.boundary_x),
            y: locate(j, disp.1, grid.ny, grid.boundary_y),
        }
    }

    /// `V[a][b] = wx_a·wy_b·d[x_a, y_b]`: the four corner values with boundary factors.
    fn corners<T: Real>(&self, d: &[T], ny: usize) -> [[T; 2]; 2] {
        let v = |a: usize, b: usize| {
            T::from_f64(self.x.w[a] * self.y.w[b]) * d[self.x.idx[a] * ny + self.y.idx[b]]
        };
        [[v(0, 0), v(0, 1)], [v(1, 0), v(1, 1)]]
    }

    fn fractions<T: Real>(&self) -> (T, T) {
        (T::from_f64(self.x.f), T::from_f64(self.y.f))
    }
}

/// One semi-Lagrangian step of the field `d` (shape `[nx, ny]`) by the velocity
/// `u` (shape `[2, nx, ny]`, components `[u_x, u_y]`) with bilinear
/// interpolation; see the [module docs](self).
///
/// # Errors
/// As [`semi_lagrangian1`].
pub fn semi_lagrangian2<T: Real>(
    grid: &Grid2,
    dt: f64,
    d: ArrayView2<'_, T>,
    u: ArrayView3<'_, T>,
) -> Result<Array2<T>> {
    check_dt(OP_2D, dt)?;
    let (nx, ny) = (grid.nx, grid.ny);
    check_shape(OP_2D, &grid.shape(), &d)?;
    check_shape(OP_2D, &[2, nx, ny], &u)?;
    let (d, u) = (d.as_standard_layout(), u.as_standard_layout());
    let (ds, us) = (d.as_slice().unwrap(), u.as_slice().unwrap());
    check_finite_velocity(OP_2D, us)?;
    let (ux, uy) = us.split_at(nx * ny);
    let (ax, ay) = (dt / grid.dx, dt / grid.dy);
    let one = T::one();
    let out = Array2::from_shape_fn((nx, ny), |(i, j)| {
        let k = i * ny + j;
        let s = Sample2::at(grid, i, j, (ux[k].as_f64() * ax, uy[k].as_f64() * ay));
        let v = s.corners(ds, ny);
        let (fx, fy) = s.fractions::<T>();
        (one - fx) * ((one - fy) * v[0][0] + fy * v[0][1])
            + fx * ((one - fy) * v[1][0] + fy * v[1][1])
    });
    Ok(out)
}

/// The vector–Jacobian product of [`semi_lagrangian2`]: `∂L/∂d` (`[nx, ny]`)
/// and `∂L/∂u` (`[2, nx, ny]`) as `wants` asks.
///
/// # Errors
/// As [`semi_lagrangian1`].
pub fn semi_lagrangian2_vjp<T: Real>(
    grid: &Grid2,
    dt: f64,
    d: ArrayView2<'_, T>,
    u: ArrayView3<'_, T>,
    grad_out: ArrayView2<'_, T>,
    wants: Wants,
) -> Result<AdvectionGrads<Array2<T>, Array3<T>>> {
    check_dt(OP_2D, dt)?;
    let (nx, ny) = (grid.nx, grid.ny);
    check_shape(OP_2D, &grid.shape(), &d)?;
    check_shape(OP_2D, &grid.shape(), &grad_out)?;
    check_shape(OP_2D, &[2, nx, ny], &u)?;
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
    check_finite_velocity(OP_2D, us)?;
    let (ux, uy) = us.split_at(nx * ny);
    let (ax, ay) = (dt / grid.dx, dt / grid.dy);
    let mut gd = wants.field.then(|| Array2::<T>::zeros((nx, ny)));
    let mut gu = wants.velocity.then(|| Array3::<T>::zeros((2, nx, ny)));
    let one = T::one();
    let (max, may) = (T::from_f64(-ax), T::from_f64(-ay));
    for i in 0..nx {
        for j in 0..ny {
            let k = i * ny + j;
            let s = Sample2::at(grid, i, j, (ux[k].as_f64() * ax, uy[k].as_f64() * ay));
            let (fx, fy) = s.fractions::<T>();
            let gk = gs[k];
            if let Some(gd) = gd.as_mut() {
                let wx = [(1.0 - s.x.f) * s.x.w[0], s.x.f * s.x.w[1]];
                let wy = [(1.0 - s.y.f) * s.y.w[0], s.y.f * s.y.w[1]];
                for a in 0..2 {
                    for b in 0..2 {
                        gd[[s.x.idx[a], s.y.idx[b]]] += T::from_f64(wx[a] * wy[b]) * gk;
                    }
                }
            }
            if let Some(gu) = gu.as_mut() {
                let v = s.corners(ds, ny);
                // ∂d'/∂s_x = (1 − f_y)(V₁₀ − V₀₀) + f_y (V₁₁ − V₀₁), ∂s_x/∂u_x = −dt/dx
                let slope_x = (one - fy) * (v[1][0] - v[0][0]) + fy * (v[1][1] - v[0][1]);
                let slope_y = (one - fx) * (v[0][1] - v[0][0]) + fx * (v[1][1] - v[1][0]);
                gu[[0, i, j]] = max * gk * slope_x;
                gu[[1, i, j]] = may * gk * slope_y;
            }
        }
    }
    Ok(AdvectionGrads {
        field: gd,
        velocity: gu,
    })
}

/// Semi-Lagrangian advection on a 1D grid (field and velocity `[n]`): an
/// [`AdvectionScheme`] and a tape op with inputs `[d, u]`
/// (`tape.apply(SemiLagrangian1::new(grid, dt), &[d, u])`). Self-advection
/// (`u = d`, Burgers) passes the same variable twice; the tape sums the two
/// gradients.
#[derive(Debug, Clone, Copy)]
pub struct SemiLagrangian1 {
    /// The grid.
    pub grid: Grid1,
    /// The time step.
    pub dt: f64,
}

impl SemiLagrangian1 {
    /// The scheme on `grid` with time step `dt`.
    pub fn new(grid: Grid1, dt: f64) -> Self {
        SemiLagrangian1 { grid, dt }
    }
}

impl<T: Real> AdvectionScheme<T> for SemiLagrangian1 {
    type Field = Ix1;
    type Velocity = Ix1;

    fn name(&self) -> &'static str {
        OP_1D
    }

    fn step(&self, d: ArrayView1<'_, T>, u: ArrayView1<'_, T>) -> Result<Array1<T>> {
        semi_lagrangian1(&self.grid, self.dt, d, u)
    }

    fn vjp(
        &self,
        d: ArrayView1<'_, T>,
        u: ArrayView1<'_, T>,
        grad_out: ArrayView1<'_, T>,
        wants: Wants,
    ) -> AdvectionVjp<T, Ix1, Ix1> {
        semi_lagrangian1_vjp(&self.grid, self.dt, d, u, grad_out, wants)
    }
}

/// Semi-Lagrangian advection on a 2D grid (field `[nx, ny]`, velocity
/// `[2, nx, ny]`): an [`AdvectionScheme`] and a tape op with inputs `[d, u]`.
#[derive(Debug, Clone, Copy)]
pub struct SemiLagrangian2 {
    /// The grid.
    pub grid: Grid2,
    /// The time step.
    pub dt: f64,
}

impl SemiLagrangian2 {
    /// The scheme on `grid` with time step `dt`.
    pub fn new(grid: Grid2, dt: f64) -> Self {
        SemiLagrangian2 { grid, dt }
    }
}

impl<T: Real> AdvectionScheme<T> for SemiLagrangian2 {
    type Field = Ix2;
    type Velocity = Ix3;

    fn name(&self) -> &'static str {
        OP_2D
    }

    fn step(&self, d: ArrayView2<'_, T>, u: ArrayView3<'_, T>) -> Result<Array2<T>> {
        semi_lagrangian2(&self.grid, self.dt, d, u)
    }

    fn vjp(
        &self,
        d: ArrayView2<'_, T>,
        u: ArrayView3<'_, T>,
        grad_out: ArrayView2<'_, T>,
        wants: Wants,
    ) -> AdvectionVjp<T, Ix2, Ix3> {
        semi_lagrangian2_vjp(&self.grid, self.dt, d, u, grad_out, wants)
    }
}
