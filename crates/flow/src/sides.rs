//! The vocabulary of the four sides: [`Side`], the condition on one
//! ([`Boundary`], a handle on any [`SideCondition`]), and the conditions on all
//! four ([`Sides`]).
//!
//! A side condition is a type behind one trait. The operators never ask which
//! condition a side carries, only what it does, in three answers:
//!
//! - [`SideCondition::normal`]: what the velocity normal to the side is on its
//!   faces ([`NormalVelocity`]: zero, the inflow profile, free, or wrapped);
//! - [`SideCondition::ghost`]: the tangential velocity's ghost value half a cell
//!   beyond the side, an affine function `factor · u_i + wall · U` of the inner
//!   value `u_i` and the side's differentiable wall speed `U`
//!   ([`crate::FlowParams::wall_speed`]), used by advection and diffusion;
//! - [`SideCondition::pressure`]: the pressure's condition at the side, in the
//!   vocabulary of diffphys-ops' grids ([`PressureSide`]: zero normal gradient,
//!   zero one cell outside, or wrapped).
//!
//! The conditions diffphys ships (their table is in [`crate::boundaries`]) are
//! the types [`NoSlip`], [`FreeSlip`], [`MovingWall`], [`Periodic`], [`Inflow`]
//! and [`Outflow`]. A new condition (a Navier slip wall, say) is a new type
//! implementing [`SideCondition`], passed as `Boundary::new(MySlip { .. })`; the
//! crate needs no new match arm. [`crate::SceneBuilder::build`] checks that a
//! condition's three answers fit together ([`check_condition`]).

use std::any::Any;
use std::fmt;
use std::sync::Arc;

/// The pressure's condition at a side, in diffphys-ops' vocabulary:
/// `Closed` (zero normal gradient), `ZeroDirichlet` (zero one cell outside),
/// `Periodic` (wrapped).
pub use diffphys_ops::Boundary as PressureSide;

/// One side of the rectangular domain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Side {
    /// `x = 0`.
    Left,
    /// `x = lx`.
    Right,
    /// `y = 0`.
    Bottom,
    /// `y = ly`.
    Top,
}

impl Side {
    /// The four sides in the order of [`crate::FlowParams::wall_speed`].
    pub const ALL: [Side; 4] = [Side::Left, Side::Right, Side::Bottom, Side::Top];

    /// Its position in [`Side::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }
}

impl fmt::Display for Side {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Side::Left => "left",
            Side::Right => "right",
            Side::Bottom => "bottom",
            Side::Top => "top",
        })
    }
}

/// What a side condition fixes of the velocity normal to the side, on the
/// faces that lie on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NormalVelocity {
    /// Zero (a wall): the faces are not unknowns of the flow.
    Zero,
    /// The inflow profile, one value per cell along the side
    /// ([`crate::SceneBuilder::inflow`]), a differentiable input of the step.
    Profile,
    /// Free: the projection sets it (an outflow).
    Free,
    /// Wrapped: the side is the opposite one's neighbour (periodic).
    Wraps,
}

/// The tangential velocity's ghost value half a cell beyond a side:
/// `u_g = factor · u_i + wall · U`, with `u_i` the inner value and `U` the
/// side's wall speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ghost {
    /// The weight of the inner value.
    pub factor: f64,
    /// The weight of the side's wall speed.
    pub wall: f64,
}

/// What makes a [`Boundary`] comparable and its condition's type known:
/// implemented for every `PartialEq` type, so a condition of one's own needs
/// only `#[derive(Debug, PartialEq)]`.
pub trait AnyCondition: Any {
    /// The condition as `Any`, so a caller can ask for its type.
    fn as_any(&self) -> &dyn Any;

    /// Whether `other` is a value of this type equal to this one.
    fn eq_any(&self, other: &dyn Any) -> bool;
}

impl<T: PartialEq + Any> AnyCondition for T {
    fn as_any(&self) -> &dyn Any {
        self
    }

    fn eq_any(&self, other: &dyn Any) -> bool {
        other.downcast_ref::<T>() == Some(self)
    }
}

/// A boundary condition on one side of the domain: what it does to the
/// normal velocity, the tangential velocity and the pressure (see the
/// [module docs](self)). Implement it for a condition of your own (a type
/// with `Debug` and `PartialEq`) and pass it as [`Boundary::new`].
pub trait SideCondition: fmt::Debug + Send + Sync + AnyCondition {
    /// A short name for messages (`"no_slip"`, …).
    fn name(&self) -> String;

    /// What the velocity normal to the side is on its faces.
    fn normal(&self) -> NormalVelocity;

    /// The tangential ghost value beyond the side, for cells of size `h`
    /// normal to it.
    fn ghost(&self, h: f64) -> Ghost;

    /// The pressure's condition at the side.
    fn pressure(&self) -> PressureSide;

    /// The side's wall speed `U` unless [`crate::FlowParams::wall_speed`]
    /// says otherwise (a moving lid's speed; 0 for the rest).
    fn wall_speed(&self) -> f64 {
        0.0
    }
}

/// A wall with zero velocity: ghost `−u_i`, zero normal pressure gradient.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct NoSlip;

/// A wall with zero normal velocity and zero shear: ghost `u_i`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FreeSlip;

/// A wall moving along itself at `speed` (the lid of a driven cavity):
/// positive along +x on the bottom and top, along +y on the left and right;
/// ghost `2 U − u_i`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MovingWall {
    /// Tangential speed of the wall: the default of
    /// [`crate::FlowParams::wall_speed`].
    pub speed: f64,
}

/// The side wraps to the opposite one, which must be periodic too.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Periodic;

/// A prescribed normal velocity, the inflow profile; no tangential inflow
/// (ghost `−u_i`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Inflow;

/// An open side: free normal velocity, zero-gradient tangential velocity
/// (ghost `u_i`), zero pressure one cell outside.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Outflow;

/// The shipped conditions' answers, one line each.
macro_rules! condition {
    ($t:ty, $name:expr, $normal:ident, ($factor:expr, $wall:expr), $pressure:ident $(, $speed:ident)?) => {
        impl SideCondition for $t {
            fn name(&self) -> String {
                $name.to_string()
            }
            fn normal(&self) -> NormalVelocity {
                NormalVelocity::$normal
            }
            fn ghost(&self, _h: f64) -> Ghost {
                Ghost { factor: $factor, wall: $wall }
            }
            fn pressure(&self) -> PressureSide {
                PressureSide::$pressure
            }
            $(fn wall_speed(&self) -> f64 {
                self.$speed
            })?
        }
    };
}

condition!(NoSlip, "no_slip", Zero, (-1.0, 0.0), Closed);
condition!(FreeSlip, "free_slip", Zero, (1.0, 0.0), Closed);
condition!(MovingWall, "moving_wall", Zero, (-1.0, 2.0), Closed, speed);
condition!(Periodic, "periodic", Wraps, (1.0, 0.0), Periodic);
condition!(Inflow, "inflow", Profile, (-1.0, 0.0), Closed);
condition!(Outflow, "outflow", Free, (1.0, 0.0), ZeroDirichlet);

/// The condition on one side: a cheap handle on any [`SideCondition`].
#[derive(Clone)]
pub struct Boundary(Arc<dyn SideCondition>);

impl Boundary {
    /// A handle on `condition`.
    pub fn new(condition: impl SideCondition) -> Self {
        Boundary(Arc::new(condition))
    }

    /// [`NoSlip`].
    pub fn no_slip() -> Self {
        Self::new(NoSlip)
    }

    /// [`FreeSlip`].
    pub fn free_slip() -> Self {
        Self::new(FreeSlip)
    }

    /// [`MovingWall`] at `speed`.
    pub fn moving_wall(speed: f64) -> Self {
        Self::new(MovingWall { speed })
    }

    /// [`Periodic`].
    pub fn periodic() -> Self {
        Self::new(Periodic)
    }

    /// [`Inflow`].
    pub fn inflow() -> Self {
        Self::new(Inflow)
    }

    /// [`Outflow`].
    pub fn outflow() -> Self {
        Self::new(Outflow)
    }

    /// The condition itself.
    pub fn condition(&self) -> &dyn SideCondition {
        &*self.0
    }

    /// The condition as its type `C`, if it is one.
    pub fn downcast_ref<C: SideCondition>(&self) -> Option<&C> {
        (*self.0).as_any().downcast_ref()
    }

    /// Whether this side wraps.
    pub fn is_periodic(&self) -> bool {
        self.0.normal() == NormalVelocity::Wraps
    }

    /// Whether this is a wall (zero normal velocity).
    pub fn is_wall(&self) -> bool {
        self.0.normal() == NormalVelocity::Zero
    }

    /// Whether the normal velocity on this side is the inflow profile.
    pub fn is_inflow(&self) -> bool {
        self.0.normal() == NormalVelocity::Profile
    }

    /// Whether the normal velocity on this side is free (an outflow).
    pub fn is_open(&self) -> bool {
        self.0.normal() == NormalVelocity::Free
    }

    /// See [`SideCondition::normal`].
    pub fn normal(&self) -> NormalVelocity {
        self.0.normal()
    }

    /// See [`SideCondition::ghost`].
    pub fn ghost(&self, h: f64) -> Ghost {
        self.0.ghost(h)
    }

    /// See [`SideCondition::pressure`].
    pub fn pressure(&self) -> PressureSide {
        self.0.pressure()
    }

    /// See [`SideCondition::wall_speed`].
    pub fn wall_speed(&self) -> f64 {
        self.0.wall_speed()
    }

    /// See [`SideCondition::name`].
    pub fn name(&self) -> String {
        self.0.name()
    }
}

impl fmt::Debug for Boundary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

impl PartialEq for Boundary {
    fn eq(&self, other: &Self) -> bool {
        (*self.0).eq_any((*other.0).as_any())
    }
}

impl<C: SideCondition> From<C> for Boundary {
    fn from(condition: C) -> Self {
        Boundary::new(condition)
    }
}

/// Checks that a condition's answers fit together and that the kernels can
/// carry them: a wrapped normal velocity wraps the pressure and the ghost
/// (`u_i`); a free one has zero pressure outside; a fixed one (zero or the
/// profile) a zero normal pressure gradient; the ghost's weights at the
/// sizes `hs` are finite.
///
/// # Errors
/// A message naming the condition and what does not fit.
pub fn check_condition(b: &Boundary, hs: &[f64]) -> std::result::Result<(), String> {
    let (normal, pressure) = (b.normal(), b.pressure());
    let expected = match normal {
        NormalVelocity::Wraps => PressureSide::Periodic,
        NormalVelocity::Free => PressureSide::ZeroDirichlet,
        NormalVelocity::Zero | NormalVelocity::Profile => PressureSide::Closed,
    };
    if pressure != expected {
        return Err(format!(
            "condition {}: a {normal:?} normal velocity needs the pressure side {expected:?}, \
             the condition gives {pressure:?}",
            b.name()
        ));
    }
    for &h in hs {
        let g = b.ghost(h);
        if !(g.factor.is_finite() && g.wall.is_finite()) {
            return Err(format!(
                "condition {}: its ghost at cell size {h} is {g:?}; need finite weights",
                b.name()
            ));
        }
        if normal == NormalVelocity::Wraps
            && g != (Ghost {
                factor: 1.0,
                wall: 0.0,
            })
        {
            return Err(format!(
                "condition {}: a wrapped side's ghost is the wrapped value (factor 1, wall 0), \
                 the condition gives {g:?}",
                b.name()
            ));
        }
    }
    if !b.wall_speed().is_finite() {
        return Err(format!(
            "condition {}: its wall speed is {}",
            b.name(),
            b.wall_speed()
        ));
    }
    Ok(())
}

/// The conditions on the four sides.
#[derive(Debug, Clone, PartialEq)]
pub struct Sides {
    /// `x = 0`.
    pub left: Boundary,
    /// `x = lx`.
    pub right: Boundary,
    /// `y = 0`.
    pub bottom: Boundary,
    /// `y = ly`.
    pub top: Boundary,
}

impl Sides {
    /// The same condition on all four sides.
    pub fn all(b: impl Into<Boundary>) -> Self {
        let b = b.into();
        Sides {
            left: b.clone(),
            right: b.clone(),
            bottom: b.clone(),
            top: b,
        }
    }

    /// A periodic box.
    pub fn periodic() -> Self {
        Self::all(Periodic)
    }

    /// A lid-driven cavity: no-slip walls, the top moving at `speed` along +x.
    pub fn cavity(speed: f64) -> Self {
        Sides {
            top: Boundary::moving_wall(speed),
            ..Self::all(NoSlip)
        }
    }

    /// A channel along x: inflow on the left, outflow on the right, no-slip
    /// walls at the bottom and top.
    pub fn channel() -> Self {
        Sides {
            left: Boundary::inflow(),
            right: Boundary::outflow(),
            bottom: Boundary::no_slip(),
            top: Boundary::no_slip(),
        }
    }

    /// The condition on `side`.
    pub fn get(&self, side: Side) -> &Boundary {
        match side {
            Side::Left => &self.left,
            Side::Right => &self.right,
            Side::Bottom => &self.bottom,
            Side::Top => &self.top,
        }
    }
}
