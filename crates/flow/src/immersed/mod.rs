//! A circle as a direct-forcing immersed boundary on the faces (Fadlun,
//! Verzicco, Orlandi and Mohd-Yusof 2000): a body that is not a staircase.
//!
//! With [`Interior::Solid`] (the default) the cells whose centre lies inside
//! the circle stay solid (their faces pinned to zero, the pressure system
//! without them), as for [`crate::Obstacle::cylinder`]; with
//! [`Interior::Forced`] no cell is solid, the pressure spans the body, and
//! every face inside the circle is forced to zero; with [`Interior::Closed`]
//! those faces are also closed in the pressure operator
//! ([`ImmersedCircle::pressure_faces`]), so the projection leaves them at
//! zero and no flux crosses the body's inside. Every *free* face that the Laplacian links
//! to a solid face, along either axis, is **forced**: after advection and
//! viscosity, before the projection, its velocity is replaced by the linear
//! interpolation between zero at the true wall and the next face outward.
//! For the link in direction `e` (unit, towards the body) of a forced face at
//! `p`, with the next face at `p − h e`:
//!
//! ```text
//! q = p − c,  b = q·e,  disc = b² − |q|² + r²
//! δ = max(0, −b − √max(disc, 0))            distance from p to the wall along e
//! w = δ / (δ + h)                            u = 0 at the wall, u_next at δ + h
//! u'_f = (1/n_f) Σ_links w u_next            n_f links of face f (averaged)
//! ```
//!
//! and `u'_f = u_f` on every other face. The body is the solid faces and
//! the free faces whose point lies inside the circle (those are set to zero);
//! the forced faces are the free faces outside it with a neighbour in the
//! body, each linked along every such neighbour's line. A face point that
//! moves inside the circle gets `δ = 0`; a grazing line that misses the circle takes the
//! closest approach, `δ = −b`. A link needs a free face outward; a forced
//! face without one (a gap of one cell between the body and a wall) is set
//! to zero, as the staircase would. The set of forced faces and their links is
//! fixed when the body is built (from the solid cells); `δ` follows the
//! circle `θ = (c_x, c_y, r)` smoothly while that set holds.
//!
//! **Schemes.** That is [`ForcingScheme::Direct`], the default. With
//! [`ForcingScheme::ProjectionConsistent`] the faces next to the wall are set
//! to `F(u − τ∇Pⁿ) + τ∇Pⁿ` ([`consistent_forcing`]), so that the projection
//! leaves them on the interpolation at a steady state. With
//! [`ForcingScheme::MultiDirect`] the forcing and the projection alternate
//! `K` times within the step ([`multi_direct_forcing`]), so that the slip the
//! projection leaves on the forced faces, and with it the steady state's
//! dependence on the time step, shrinks geometrically with `K`.
//!
//! **Force.** The forcing changes the momentum of the faces by
//! `Σ_forced (u'_f − u_f) dx dy` per step ([`ImmersedCircle::momentum_change`],
//! summed by [`ForcingImpulse`]); the force of the flow on the body is minus
//! that per unit time ([`crate::StepInfo::immersed_force`]), the whole force
//! with a forced interior and a steady flow, the forcing's share of it with
//! a solid one. On a closed interior the pressure on the closed faces is the
//! rest ([`ImmersedCircle::closed_pressure_force`]).
//!
//! **Adjoint.** The map is linear in the velocity; with `g` the gradient of
//! the output,
//!
//! ```text
//! ∂L/∂u_g = g_g [g not forced] + Σ_{links (f → g)} (1/n_f) w g_f
//! ∂L/∂θ   = Σ_{forced f} g_f Σ_links (1/n_f) (∂w/∂δ)(∂δ/∂θ) u_next
//! ∂w/∂δ   = h / (δ + h)²
//! ∂δ/∂c   = e + (b e − q)/√disc,   ∂δ/∂r = −r/√disc     (0 where δ is clamped)
//! ```
//!
//! (the wall point `x = p + δ e` moves along `e` so that `|x − c| = r` holds).
//!
//! **The shape on the tape.** The circle is the op's third input, a `[3]`
//! array `(c_x, c_y, r)`: [`crate::Scene::step`] records it as a constant,
//! [`crate::Scene::step_with_body`] takes it as a variable, and its gradient is
//! then one `tape.backward` like any other parameter's. The solid cells do not
//! move with `θ`: a gradient with respect to the shape is that of the forced
//! faces' interpolation, valid while no cell changes side.
//!
//! # References
//! E. A. Fadlun, R. Verzicco, P. Orlandi, J. Mohd-Yusof, *Combined
//! immersed-boundary finite-difference methods for three-dimensional complex
//! flow simulations*, J. Comput. Phys. 161 (2000) 35–60.

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2};

use std::cell::Cell;
use std::rc::Rc;
use std::sync::Arc;

use crate::boundaries::{view1, view2, FaceKind, Faces};
use crate::buffers::{narrow, wide};
use crate::grid::{FlowGrid, Lattice};
use crate::{FlowError, Result};

mod consistent;
mod multi_direct;

pub use consistent::{
    consistent_forcing, consistent_forcing_vjp, ConsistentForcing, ForcingScheme,
};
pub use multi_direct::{
    multi_direct_forcing, multi_direct_forcing_vjp, MultiDirect, MultiDirectForcing,
};

const NAME: &str = "immersed circle";

/// A circle of `center` and `radius`: the immersed body's shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    /// Its centre.
    pub center: [f64; 2],
    /// Its radius.
    pub radius: f64,
}

impl Circle {
    /// The circle, checked: finite, radius > 0.
    ///
    /// # Errors
    /// [`FlowError::InvalidParameter`] for a radius ≤ 0 or a value that is not finite.
    pub fn new(center: [f64; 2], radius: f64) -> Result<Self> {
        Circle::from_shape([center[0], center[1], radius].as_slice())
    }

    /// `(c_x, c_y, r)`, the layout of the op's shape input.
    pub fn shape(&self) -> [f64; 3] {
        [self.center[0], self.center[1], self.radius]
    }

    /// The circle of `(c_x, c_y, r)`, checked as in [`Circle::new`].
    ///
    /// # Errors
    /// [`FlowError::Shape`] for other than 3 values; those of [`Circle::new`].
    pub fn from_shape(s: &[f64]) -> Result<Self> {
        if s.len() != 3 {
            return Err(FlowError::shape(
                NAME,
                "shape (cx, cy, r)",
                &[3],
                &[s.len()],
            ));
        }
        if s.iter().any(|v| !v.is_finite()) {
            return Err(FlowError::NonFinite {
                step: NAME.into(),
                quantity: "shape (cx, cy, r)".into(),
                count: s.iter().filter(|v| !v.is_finite()).count(),
            });
        }
        if s[2] <= 0.0 {
            return Err(FlowError::parameter(
                NAME,
                "radius",
                format!("need a radius > 0, got {}", s[2]),
            ));
        }
        Ok(Circle {
            center: [s[0], s[1]],
            radius: s[2],
        })
    }

    /// `δ` and `∂δ/∂(c_x, c_y, r)` along `e` from `p` (see the [module docs](self)).
    fn wall_distance(&self, p: [f64; 2], e: [f64; 2]) -> (f64, [f64; 3]) {
        let q = [p[0] - self.center[0], p[1] - self.center[1]];
        let b = q[0] * e[0] + q[1] * e[1];
        let r = self.radius;
        let disc = b * b - (q[0] * q[0] + q[1] * q[1]) + r * r;
        if disc <= 0.0 {
            // the line misses the circle: the closest approach
            return if -b > 0.0 {
                (-b, [e[0], e[1], 0.0])
            } else {
                (0.0, [0.0; 3])
            };
        }
        let s = disc.sqrt();
        let t = -b - s;
        if t <= 0.0 {
            return (0.0, [0.0; 3]);
        }
        let dc = |k: usize| e[k] + (b * e[k] - q[k]) / s;
        (t, [dc(0), dc(1), -r / s])
    }
}

/// One link of a forced face: the next face outward and the line towards the
/// wall.
#[derive(Debug, Clone, PartialEq)]
struct Link {
    /// The next face outward, flat index in the same component.
    next: usize,
    /// The unit direction from the forced face towards the body.
    e: [f64; 2],
    /// The spacing along `e`.
    h: f64,
}

/// A forced face: its flat index, position and links.
#[derive(Debug, Clone, PartialEq)]
struct ForcedFace {
    face: usize,
    point: [f64; 2],
    links: Vec<Link>,
}

/// The forced faces of one component: the free faces inside the circle
/// (no links: set to zero), and the free faces outside it with a neighbour
/// in the body (a solid face, or a free face inside the circle), linked to it
/// through the next fluid face outward.
fn forced_faces(
    grid: &FlowGrid,
    lattice: Lattice,
    kinds: &[FaceKind],
    solid: &Array2<bool>,
    circle: Circle,
) -> Vec<ForcedFace> {
    let [na, nb] = grid.shape(lattice);
    let touches_solid = |a: usize, b: usize| match lattice {
        Lattice::FaceX => {
            let (lo, hi) = grid.x_face_cells(a);
            [lo, hi].into_iter().flatten().any(|i| solid[[i, b]])
        }
        _ => {
            let (lo, hi) = grid.y_face_cells(b);
            [lo, hi].into_iter().flatten().any(|j| solid[[a, j]])
        }
    };
    let inside = |a: usize, b: usize| {
        let [x, y] = grid.position(lattice, a, b);
        let [cx, cy] = circle.center;
        (x - cx).powi(2) + (y - cy).powi(2) < circle.radius * circle.radius
    };
    let free = |a: usize, b: usize| kinds[a * nb + b] == FaceKind::Free;
    let in_body = |a: usize, b: usize| {
        (kinds[a * nb + b] == FaceKind::Zero && touches_solid(a, b)) || (free(a, b) && inside(a, b))
    };
    let at = |a: usize, b: usize, (da, db): (isize, isize)| {
        let (a, b) = (a as isize + da, b as isize + db);
        (a >= 0 && b >= 0 && (a as usize) < na && (b as usize) < nb)
            .then_some((a as usize, b as usize))
    };
    let mut out = Vec::new();
    for a in 0..na {
        for b in 0..nb {
            if !free(a, b) {
                continue;
            }
            let point = grid.position(lattice, a, b);
            let face = a * nb + b;
            if inside(a, b) {
                out.push(ForcedFace {
                    face,
                    point,
                    links: Vec::new(),
                });
                continue;
            }
            let mut links = Vec::new();
            let mut near = false;
            for (da, db) in [(1isize, 0isize), (-1, 0), (0, 1), (0, -1)] {
                if !at(a, b, (da, db)).is_some_and(|(ta, tb)| in_body(ta, tb)) {
                    continue;
                }
                near = true;
                let Some((oa, ob)) = at(a, b, (-da, -db)) else {
                    continue;
                };
                if !free(oa, ob) || inside(oa, ob) {
                    continue;
                }
                let h = if da != 0 { grid.dx } else { grid.dy };
                links.push(Link {
                    next: oa * nb + ob,
                    e: [da as f64, db as f64],
                    h,
                });
            }
            if near {
                out.push(ForcedFace { face, point, links });
            }
        }
    }
    out
}

/// The immersed circle on a grid: its forced faces and their links, fixed
/// at construction (see the [module docs](self) for the formula).
#[derive(Debug, Clone, PartialEq)]
pub struct ImmersedCircle {
    grid: FlowGrid,
    circle: Circle,
    /// Whether its zero faces are closed in the pressure operator
    /// ([`Interior::Closed`]).
    closed: bool,
    x: Vec<ForcedFace>,
    y: Vec<ForcedFace>,
}

impl ImmersedCircle {
    /// The circle's forced faces on `grid`, whose faces are `faces` and solid
    /// cells `solid` (those of [`crate::Obstacle::cylinder`] of the same circle).
    ///
    /// # Errors
    /// [`FlowError::Shape`] for a mask that is not `[nx, ny]`;
    /// [`FlowError::InvalidScene`] for a circle that does not lie inside the domain.
    pub fn new(
        grid: &FlowGrid,
        faces: &Faces,
        solid: &Array2<bool>,
        circle: Circle,
    ) -> Result<Self> {
        if solid.shape() != grid.cell_shape() {
            return Err(FlowError::shape(
                NAME,
                "solid mask",
                &grid.cell_shape(),
                solid.shape(),
            ));
        }
        let [lx, ly] = grid.size();
        let ([cx, cy], r) = (circle.center, circle.radius);
        if cx - r < 0.0 || cx + r > lx || cy - r < 0.0 || cy + r > ly {
            return Err(FlowError::scene(
                NAME,
                format!(
                    "circle of radius {r} at {:?} does not fit in the domain {lx} × {ly}",
                    circle.center
                ),
            ));
        }
        Ok(ImmersedCircle {
            grid: grid.clone(),
            circle,
            closed: false,
            x: forced_faces(
                grid,
                Lattice::FaceX,
                faces.of(Lattice::FaceX),
                solid,
                circle,
            ),
            y: forced_faces(
                grid,
                Lattice::FaceY,
                faces.of(Lattice::FaceY),
                solid,
                circle,
            ),
        })
    }

    /// The circle it was built for.
    pub fn circle(&self) -> Circle {
        self.circle
    }

    /// The grid.
    pub fn grid(&self) -> &FlowGrid {
        &self.grid
    }

    /// How many faces are forced: `(x-faces, y-faces)`.
    pub fn forced_count(&self) -> (usize, usize) {
        (self.x.len(), self.y.len())
    }

    /// 1 on the forced faces, 0 elsewhere: `(x, y)`.
    pub fn forced_mask(&self) -> (Array2<f64>, Array2<f64>) {
        let mask = |shape: [usize; 2], forced: &[ForcedFace]| {
            let mut m = Array2::zeros(shape);
            let flat = m.as_slice_mut().expect("standard layout");
            forced.iter().for_each(|f| flat[f.face] = 1.0);
            m
        };
        (
            mask(self.grid.shape_x(), &self.x),
            mask(self.grid.shape_y(), &self.y),
        )
    }

    /// `Σ_forced (after_f − before_f) dx dy` per component: the momentum the
    /// forcing added to the faces in going from `before` to `after` (each
    /// `(u_x, u_y)` on the grid's faces).
    ///
    /// # Panics
    /// For arrays not on the grid's faces (a broken internal invariant: the
    /// op checks them first).
    pub fn momentum_change<T: Real>(
        &self,
        before: (ArrayView2<'_, T>, ArrayView2<'_, T>),
        after: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    ) -> [f64; 2] {
        let cell = self.grid.dx * self.grid.dy;
        let sum = |forced: &[ForcedFace], b: ArrayView2<'_, T>, a: ArrayView2<'_, T>| {
            let (b, a) = (wide(b), wide(a));
            cell * forced.iter().map(|f| a[f.face] - b[f.face]).sum::<f64>()
        };
        [
            sum(&self.x, before.0, after.0),
            sum(&self.y, before.1, after.1),
        ]
    }

    /// The body with its zero faces closed in the pressure operator
    /// ([`Interior::Closed`]: the scene builds its pressure system on
    /// [`ImmersedCircle::pressure_faces`]).
    pub(crate) fn closed(mut self) -> Self {
        self.closed = true;
        self
    }

    /// `−Σ_closed (G P)_f dx dy`: the force of the pressure `P` on the faces
    /// closed in the pressure operator (zero unless [`Interior::Closed`]).
    /// The projection moves no closed face, so the momentum `τ G P` it would
    /// give them is the body's: on a closed interior the force on the body is
    /// the forcing's exchange plus `τ/dt` times this, `P` the projection's.
    ///
    /// # Panics
    /// For a pressure not on the grid's cells (a broken internal invariant).
    pub fn closed_pressure_force(&self, pressure: ArrayView2<'_, f64>) -> [f64; 2] {
        if !self.closed {
            return [0.0; 2];
        }
        let g = &self.grid;
        let cell = g.dx * g.dy;
        let p = |i: usize, j: usize| pressure[[i, j]];
        let mut f = [0.0; 2];
        for ff in self.x.iter().filter(|f| f.links.is_empty()) {
            let (a, j) = (ff.face / g.ny, ff.face % g.ny);
            if let (Some(lo), Some(hi)) = g.x_face_cells(a) {
                f[0] -= cell * (p(hi, j) - p(lo, j)) / g.dx;
            }
        }
        let [_, nfy] = g.shape_y();
        for ff in self.y.iter().filter(|f| f.links.is_empty()) {
            let (i, b) = (ff.face / nfy, ff.face % nfy);
            if let (Some(lo), Some(hi)) = g.y_face_cells(b) {
                f[1] -= cell * (p(i, hi) - p(i, lo)) / g.dy;
            }
        }
        f
    }

    /// `faces` with the faces that the forcing sets to zero (the forced faces
    /// without links: inside the circle, or without a fluid face outward)
    /// closed, and the cells of `grid` left with no open face: the faces and
    /// the solid cells of the pressure operator for [`Interior::Closed`].
    pub fn pressure_faces(&self, faces: &Faces) -> (Faces, Array2<bool>) {
        let mut closed = faces.clone();
        for (forced, kinds) in [(&self.x, &mut closed.x), (&self.y, &mut closed.y)] {
            for f in forced.iter().filter(|f| f.links.is_empty()) {
                kinds[f.face] = FaceKind::Zero;
            }
        }
        let g = &self.grid;
        let mut open = Array2::from_elem(g.cell_shape(), false);
        let [nfx, _] = g.shape_x();
        for f in 0..nfx {
            let (lo, hi) = g.x_face_cells(f);
            for j in 0..g.ny {
                if closed.x[f * g.ny + j] == FaceKind::Free {
                    lo.into_iter().chain(hi).for_each(|i| open[[i, j]] = true);
                }
            }
        }
        let [_, nfy] = g.shape_y();
        for i in 0..g.nx {
            for f in 0..nfy {
                if closed.y[i * nfy + f] == FaceKind::Free {
                    let (lo, hi) = g.y_face_cells(f);
                    lo.into_iter().chain(hi).for_each(|j| open[[i, j]] = true);
                }
            }
        }
        (closed, open.mapv(|o| !o))
    }

    fn components(&self) -> [(&[ForcedFace], [usize; 2]); 2] {
        [
            (&self.x, self.grid.shape_x()),
            (&self.y, self.grid.shape_y()),
        ]
    }

    fn check<T>(
        &self,
        ux: ArrayView2<'_, T>,
        uy: ArrayView2<'_, T>,
        shape: ArrayView1<'_, T>,
    ) -> Result<()> {
        self.grid.check_velocity(NAME, ux, uy)?;
        if shape.len() != 3 {
            return Err(FlowError::shape(
                NAME,
                "shape (cx, cy, r)",
                &[3],
                shape.shape(),
            ));
        }
        Ok(())
    }
}

/// The forced velocity `u'` (see the [module docs](self)) for the circle of
/// `shape = (c_x, c_y, r)` on the faces of `body`.
///
/// # Errors
/// [`FlowError::Shape`] for wrong shapes; those of [`Circle::from_shape`].
pub fn immersed_forcing<T: Real>(
    body: &ImmersedCircle,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    shape: ArrayView1<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    body.check(ux, uy, shape)?;
    let circle = Circle::from_shape(&shape.iter().map(|v| v.as_f64()).collect::<Vec<_>>())?;
    let [(fx, sx), (fy, sy)] = body.components();
    let force = |forced: &[ForcedFace], shape: [usize; 2], u: ArrayView2<'_, T>| {
        let u_in = wide(u);
        let mut out = u_in.to_vec();
        for f in forced {
            let share = 1.0 / f.links.len().max(1) as f64;
            out[f.face] = f
                .links
                .iter()
                .map(|l| {
                    let (d, _) = circle.wall_distance(f.point, l.e);
                    share * d / (d + l.h) * u_in[l.next]
                })
                .sum();
        }
        narrow(shape, out)
    };
    Ok((force(fx, sx, ux), force(fy, sy, uy)))
}

/// The vector–Jacobian product of [`immersed_forcing`]: `(∂L/∂u_x, ∂L/∂u_y,
/// ∂L/∂shape)` given the gradients `(g_x, g_y)` of its outputs.
///
/// # Errors
/// As [`immersed_forcing`].
pub fn immersed_forcing_vjp<T: Real>(
    body: &ImmersedCircle,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    shape: ArrayView1<'_, T>,
    gx: ArrayView2<'_, T>,
    gy: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>, Array1<T>)> {
    body.check(ux, uy, shape)?;
    body.grid.check_velocity(NAME, gx, gy)?;
    let circle = Circle::from_shape(&shape.iter().map(|v| v.as_f64()).collect::<Vec<_>>())?;
    let mut g_shape = [0.0; 3];
    let [(fx, sx), (fy, sy)] = body.components();
    let mut adjoint =
        |forced: &[ForcedFace], shape: [usize; 2], u: ArrayView2<'_, T>, g: ArrayView2<'_, T>| {
            let u = wide(u);
            let g_out = wide(g);
            let mut g_in = g_out.to_vec();
            forced.iter().for_each(|f| g_in[f.face] = 0.0);
            for f in forced {
                let share = 1.0 / f.links.len().max(1) as f64;
                for l in &f.links {
                    let (d, dd) = circle.wall_distance(f.point, l.e);
                    g_in[l.next] += share * d / (d + l.h) * g_out[f.face];
                    let dw = share * l.h / ((d + l.h) * (d + l.h));
                    for k in 0..3 {
                        g_shape[k] += g_out[f.face] * dw * dd[k] * u[l.next];
                    }
                }
            }
            narrow(shape, g_in)
        };
    let gx = adjoint(fx, sx, ux, gx);
    let gy = adjoint(fy, sy, uy, gy);
    Ok((gx, gy, g_shape.iter().map(|&v| T::from_f64(v)).collect()))
}

/// What lies inside an immersed circle ([`crate::SceneBuilder::immersed_interior`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Interior {
    /// The cells of [`crate::Obstacle::cylinder`] of the same circle are solid:
    /// their faces pinned to zero, the pressure system without them. The
    /// pressure and the viscosity then also act on the staircase, so the
    /// forcing's momentum ([`ForcingImpulse`]) is only part of the force.
    #[default]
    Solid,
    /// No solid cell: every face inside the circle is forced to zero and the
    /// pressure spans the body (Fadlun et al. 2000). The forcing is then the
    /// whole exchange with the body, and the force on it is minus the
    /// forcing's momentum per unit time ([`crate::StepInfo::immersed_force`]).
    Forced,
    /// As [`Interior::Forced`] for the velocity, and the faces the forcing
    /// sets to zero (those inside the circle) are also closed in the pressure
    /// operator, as a solid cell's faces are ([`ImmersedCircle::pressure_faces`]):
    /// the projection leaves them at zero, so no flux crosses the body's inside.
    /// The cells with no open face drop out of the pressure system.
    Closed,
}

/// The momentum the immersed forcing has added to the faces,
/// `Σ_forced (u'_f − u*_f) dx dy` per component (`u*` the velocity it was
/// given, `u'` its output), summed over every forward run since it was made;
/// shared by its clones (as [`crate::pressure::SolveCounter`]).
#[derive(Debug, Clone, Default)]
pub struct ForcingImpulse(Rc<Cell<[f64; 2]>>);

impl ForcingImpulse {
    /// Zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// The momentum added so far, `[x, y]`.
    pub fn total(&self) -> [f64; 2] {
        self.0.get()
    }

    /// Adds the momentum the forcing of `body` changed in going from
    /// `before` to `after` ([`ImmersedCircle::momentum_change`]).
    fn record<T: Real>(
        &self,
        body: &ImmersedCircle,
        before: (ArrayView2<'_, T>, ArrayView2<'_, T>),
        after: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    ) {
        self.add(body.momentum_change(before, after));
    }

    /// Adds the momentum `m`, `[x, y]`.
    fn add(&self, m: [f64; 2]) {
        let t = self.0.get();
        self.0.set([t[0] + m[0], t[1] + m[1]]);
    }
}

/// [`immersed_forcing`] as a tape op: inputs `[u_x, u_y, shape]`, outputs
/// `[u_x', u_y']`. It keeps nothing beyond its inputs; each forward adds the
/// momentum it changed to [`ImmersedForcing::impulse`].
#[derive(Debug, Clone)]
pub struct ImmersedForcing {
    /// The body and its forced faces.
    pub body: Arc<ImmersedCircle>,
    /// Where the forwards' momentum changes go.
    pub impulse: ForcingImpulse,
}

impl ImmersedForcing {
    /// The op for `body`, with a fresh [`ForcingImpulse`].
    pub fn new(body: Arc<ImmersedCircle>) -> Self {
        ImmersedForcing {
            body,
            impulse: ForcingImpulse::new(),
        }
    }
}

impl<T: Real> Op<T> for ImmersedForcing {
    fn name(&self) -> &str {
        NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(NAME, 3, inputs.len())?;
        let (ux0, uy0) = (view2(&inputs[0])?, view2(&inputs[1])?);
        let (ux, uy) = immersed_forcing(&self.body, ux0, uy0, view1(&inputs[2])?)?;
        self.impulse
            .record(&self.body, (ux0, uy0), (ux.view(), uy.view()));
        Ok(vec![ux.into_dyn(), uy.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let (gx, gy) = (args.grad_output_or_zeros(0), args.grad_output_or_zeros(1));
        let (jx, jy, js) = immersed_forcing_vjp(
            &self.body,
            view2(args.input(0))?,
            view2(args.input(1))?,
            view1(args.input(2))?,
            view2(&gx.view())?,
            view2(&gy.view())?,
        )?;
        Ok(vec![
            args.needs(0).then(|| jx.into_dyn()),
            args.needs(1).then(|| jy.into_dyn()),
            args.needs(2).then(|| js.into_dyn()),
        ])
    }
}
