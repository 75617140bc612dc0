//! Uniform grids and their boundaries.

/// What lies beyond the edge of a grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Boundary {
    /// The domain wraps around: the cell after the last is the first.
    Periodic,
    /// The field is zero beyond the edge (a ghost value of 0; for a cell-centred
    /// Laplacian the ghost is mirrored so the field is zero on the wall itself).
    ZeroDirichlet,
    /// Closed walls: zero normal flow, zero normal derivative (Neumann) for
    /// cell-centred scalars such as pressure.
    Closed,
}
