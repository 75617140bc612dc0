//! The staggered (MAC) layout every fluid operator of diffphys shares: which
//! faces an axis stores, which cells a face lies between, where an entry sits.
//!
//! A domain `[0, lx] × [0, ly]` is cut into `nx × ny` cells of size `dx × dy`;
//! axis 0 is x, axis 1 is y. Pressure and passive scalars live at cell centres
//! (`[nx, ny]`, cell `(i, j)` at `((i + ½) dx, (j + ½) dy)`), the x-velocity on
//! the faces normal to x, the y-velocity on the faces normal to y:
//!
//! | array | shape, non-periodic axis | shape, periodic axis | entry `[a, b]` at |
//! | --- | --- | --- | --- |
//! | `u_x` | `[nx + 1, ny]` | `[nx, ny]` | `(a dx, (b + ½) dy)` |
//! | `u_y` | `[nx, ny + 1]` | `[nx, ny]` | `((a + ½) dx, b dy)` |
//!
//! Face `f` along an axis of `n` cells lies between cells `f − 1` and `f`
//! ([`face_cells`]): outside the domain where that index is out of range, so
//! a non-periodic axis stores its two boundary faces `0` and `n`; wrapped on a
//! periodic axis, which stores `n` faces (face `n` is face `0`).
//!
//! Both fluid stacks use this one layout: [`crate::mac::MacGrid`] (pressure
//! projection, whose boundary faces are open or closed by the pressure's side
//! condition, [`crate::Boundary`]) and diffphys-flow's `FlowGrid` (the flow
//! step, whose boundary faces carry the velocity's side conditions). So the
//! arrays of one are the arrays of the other.

/// The faces an axis of `n` cells stores: `n + 1` (both boundary faces), or
/// `n` on a periodic axis.
#[inline]
pub fn face_count(n: usize, periodic: bool) -> usize {
    n + usize::from(!periodic)
}

/// The cells on the low and high side of face `f` of an axis of `n` cells:
/// `f − 1` and `f`, `None` outside a non-periodic axis, wrapped on a periodic
/// one.
#[inline]
pub fn face_cells(f: usize, n: usize, periodic: bool) -> (Option<usize>, Option<usize>) {
    if periodic {
        // (f − 1) mod n and f mod n, without a division in the inner loops
        let hi = if f < n { f } else { f % n };
        let lo = if hi == 0 { n - 1 } else { hi - 1 };
        (Some(lo), Some(hi))
    } else {
        (f.checked_sub(1), (f < n).then_some(f))
    }
}

/// One of the two velocity components, or a cell-centred scalar: which lattice
/// an array lives on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lattice {
    /// The x-velocity on the x-faces.
    FaceX,
    /// The y-velocity on the y-faces.
    FaceY,
    /// Cell centres (pressure, scalars).
    Cell,
}

impl Lattice {
    /// The position of entry `[0, 0]` from the origin, in cells along x and y.
    pub fn offsets(self) -> (f64, f64) {
        match self {
            Lattice::FaceX => (0.0, 0.5),
            Lattice::FaceY => (0.5, 0.0),
            Lattice::Cell => (0.5, 0.5),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faces_lie_between_their_cells() {
        assert_eq!(face_count(5, false), 6);
        assert_eq!(face_count(5, true), 5);
        assert_eq!(face_cells(0, 5, false), (None, Some(0)));
        assert_eq!(face_cells(3, 5, false), (Some(2), Some(3)));
        assert_eq!(face_cells(5, 5, false), (Some(4), None));
        assert_eq!(face_cells(0, 5, true), (Some(4), Some(0)));
        assert_eq!(face_cells(5, 5, true), (Some(4), Some(0)));
        assert_eq!(face_cells(0, 1, true), (Some(0), Some(0)));
    }
}
