//! The vocabulary of the four sides: [`Side`], the condition on one
//! ([`Boundary`]), and the conditions on all four ([`Sides`]).
//!
//! What each condition does to the velocity and the pressure is tabled in
//! [`crate::boundaries`]; this module only names them, below the grid that
//! carries them.

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

impl std::fmt::Display for Side {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Side::Left => "left",
            Side::Right => "right",
            Side::Bottom => "bottom",
            Side::Top => "top",
        })
    }
}

/// The condition on one side (see the [module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Boundary {
    /// A wall with zero velocity.
    NoSlip,
    /// A wall with zero normal velocity and zero shear.
    FreeSlip,
    /// A wall moving along itself at `speed` (the lid of a driven cavity):
    /// positive along +x on the bottom and top, along +y on the left and right.
    /// `speed` is the default of [`crate::FlowParams::wall_speed`].
    MovingWall {
        /// Tangential speed of the wall.
        speed: f64,
    },
    /// The side wraps to the opposite one, which must be periodic too.
    Periodic,
    /// A prescribed normal velocity: the inflow profile, one value per cell
    /// along the side ([`crate::SceneBuilder::inflow`]).
    Inflow,
    /// An open side: zero-gradient velocity, zero pressure outside.
    Outflow,
}

impl Boundary {
    /// Whether this side wraps.
    pub fn is_periodic(&self) -> bool {
        matches!(self, Boundary::Periodic)
    }

    /// Whether this is a wall (no-slip, free-slip or moving).
    pub fn is_wall(&self) -> bool {
        matches!(
            self,
            Boundary::NoSlip | Boundary::FreeSlip | Boundary::MovingWall { .. }
        )
    }

    /// The tangential ghost value as `factor · u_inner + wall · U`.
    pub(crate) fn ghost(&self) -> (f64, f64) {
        match self {
            Boundary::NoSlip | Boundary::Inflow => (-1.0, 0.0),
            Boundary::MovingWall { .. } => (-1.0, 2.0),
            Boundary::FreeSlip | Boundary::Outflow | Boundary::Periodic => (1.0, 0.0),
        }
    }
}

/// The conditions on the four sides.
#[derive(Debug, Clone, Copy, PartialEq)]
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
    pub fn all(b: Boundary) -> Self {
        Sides {
            left: b,
            right: b,
            bottom: b,
            top: b,
        }
    }

    /// A periodic box.
    pub fn periodic() -> Self {
        Self::all(Boundary::Periodic)
    }

    /// A lid-driven cavity: no-slip walls, the top moving at `speed` along +x.
    pub fn cavity(speed: f64) -> Self {
        Sides {
            top: Boundary::MovingWall { speed },
            ..Self::all(Boundary::NoSlip)
        }
    }

    /// A channel along x: inflow on the left, outflow on the right, no-slip
    /// walls at the bottom and top.
    pub fn channel() -> Self {
        Sides {
            left: Boundary::Inflow,
            right: Boundary::Outflow,
            bottom: Boundary::NoSlip,
            top: Boundary::NoSlip,
        }
    }

    /// The condition on `side`.
    pub fn get(&self, side: Side) -> Boundary {
        match side {
            Side::Left => self.left,
            Side::Right => self.right,
            Side::Bottom => self.bottom,
            Side::Top => self.top,
        }
    }
}
