//! The pressure operator of a [`MacGrid`]: the face-weighted [`MacPoisson`]
//! and [`PressureOperator`], which picks the 5-point stencil where that is
//! the same matrix.

use diffphys_tape::Real;
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD, IxDyn};

use super::MacGrid;
use crate::linear::wide;
use crate::stencil::Laplacian2;
use crate::LinearOperator;

/// The face-weighted pressure operator `A = Gᵀ W G + (I − P_active)` of a
/// [`MacGrid`]: per active cell, `(A p)_c = Σ_open faces (p_c − p_other)/h²`
/// (`p_other = 0` outside an open boundary); inactive cells map to themselves.
/// Symmetric positive semidefinite (definite with an open boundary); adjoint
/// `Aᵀ = A`.
#[derive(Debug, Clone, PartialEq)]
pub struct MacPoisson {
    mac: MacGrid,
    shape: [usize; 2],
    /// `1/dx²`, `1/dy²`.
    coef: [f64; 2],
}

impl MacPoisson {
    /// The operator of `mac`.
    pub fn new(mac: MacGrid) -> Self {
        let g = mac.grid;
        MacPoisson {
            shape: g.shape(),
            coef: [1.0 / (g.dx * g.dx), 1.0 / (g.dy * g.dy)],
            mac,
        }
    }

    /// The staggered grid.
    pub fn mac(&self) -> &MacGrid {
        &self.mac
    }

    /// Every open face as `(low cell, high cell, coefficient)` with flat cell
    /// indices (`None` outside); faces whose two sides are the same cell (a
    /// periodic axis of one cell) carry no flux and are skipped.
    fn faces(&self) -> Vec<(Option<usize>, Option<usize>, f64)> {
        let m = &self.mac;
        let (nx, ny) = (m.grid.nx, m.grid.ny);
        let mut faces = Vec::new();
        for f in 0..m.ax.count() {
            let (lo, hi) = m.ax.sides(f);
            for j in 0..ny {
                if m.open_x[f * ny + j] && (lo != hi) {
                    faces.push((lo.map(|i| i * ny + j), hi.map(|i| i * ny + j), self.coef[0]));
                }
            }
        }
        let nfy = m.ay.count();
        for i in 0..nx {
            for f in 0..nfy {
                let (lo, hi) = m.ay.sides(f);
                if m.open_y[i * nfy + f] && (lo != hi) {
                    faces.push((lo.map(|j| i * ny + j), hi.map(|j| i * ny + j), self.coef[1]));
                }
            }
        }
        faces
    }

    fn inactive(&self) -> impl Iterator<Item = usize> + '_ {
        self.mac.mask.iter().flat_map(|m| {
            m.as_slice()
                .iter()
                .enumerate()
                .filter(|(_, &a)| !a)
                .map(|(c, _)| c)
        })
    }

    /// `out = A x` on row-major slices.
    fn run<T: Real>(&self, x: &[T], out: &mut [T]) {
        let m = &self.mac;
        let (nx, ny) = (m.grid.nx, m.grid.ny);
        out.fill(T::zero());
        let cx = T::from_f64(self.coef[0]);
        for f in 0..m.ax.count() {
            let (lo, hi) = m.ax.sides(f);
            if lo == hi {
                continue;
            }
            let open = &m.open_x[f * ny..(f + 1) * ny];
            for (j, _) in open.iter().enumerate().filter(|(_, &o)| o) {
                let at = |c: Option<usize>| c.map_or(T::zero(), |i| x[i * ny + j]);
                let flux = (at(hi) - at(lo)) * cx;
                if let Some(i) = lo {
                    out[i * ny + j] -= flux;
                }
                if let Some(i) = hi {
                    out[i * ny + j] += flux;
                }
            }
        }
        let cy = T::from_f64(self.coef[1]);
        let nfy = m.ay.count();
        for f in 0..nfy {
            let (lo, hi) = m.ay.sides(f);
            if lo == hi {
                continue;
            }
            for i in 0..nx {
                if m.open_y[i * nfy + f] {
                    let at = |c: Option<usize>| c.map_or(T::zero(), |j| x[i * ny + j]);
                    let flux = (at(hi) - at(lo)) * cy;
                    if let Some(j) = lo {
                        out[i * ny + j] -= flux;
                    }
                    if let Some(j) = hi {
                        out[i * ny + j] += flux;
                    }
                }
            }
        }
        for c in self.inactive() {
            out[c] = x[c];
        }
    }

    /// `out = A x`, returning `<x, A x>` accumulated in `f64`.
    fn apply_slices<T: Real>(&self, x: ArrayViewD<'_, T>, mut out: ArrayViewMutD<'_, T>) -> f64 {
        let x = x.as_standard_layout();
        let xs = x.as_slice().expect("standard layout is contiguous");
        let dot = |o: &[T]| {
            xs.iter()
                .zip(o)
                .fold(0.0, |acc, (&a, &b)| acc + wide(a) * wide(b))
        };
        if let Some(o) = out.as_slice_mut() {
            self.run(xs, o);
            return dot(o);
        }
        let mut buf = vec![T::zero(); xs.len()];
        self.run(xs, &mut buf);
        for (o, &b) in out.iter_mut().zip(&buf) {
            *o = b;
        }
        dot(&buf)
    }
}

impl<T: Real> LinearOperator<T> for MacPoisson {
    fn name(&self) -> &str {
        "mac_poisson"
    }
    fn input_shape(&self) -> &[usize] {
        &self.shape
    }
    fn output_shape(&self) -> &[usize] {
        &self.shape
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.apply_slices(x, out);
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.apply_slices(y, out);
    }
    fn apply_into_dot(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) -> f64 {
        self.apply_slices(x, out)
    }
    fn is_symmetric(&self) -> bool {
        true
    }
    fn diagonal(&self) -> Option<ArrayD<T>> {
        let mut d = vec![0.0; self.shape[0] * self.shape[1]];
        for (lo, hi, c) in self.faces() {
            for cell in [lo, hi].into_iter().flatten() {
                d[cell] += c;
            }
        }
        for c in self.inactive() {
            d[c] = 1.0;
        }
        Some(
            ArrayD::from_shape_vec(IxDyn(&self.shape), d.into_iter().map(T::from_f64).collect())
                .expect("one per cell"),
        )
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        let n = self.shape[0] * self.shape[1];
        let mut t: Vec<(usize, usize, f64)> = (0..n).map(|c| (c, c, 0.0)).collect();
        for (lo, hi, c) in self.faces() {
            for cell in [lo, hi].into_iter().flatten() {
                t.push((cell, cell, c));
            }
            if let (Some(a), Some(b)) = (lo, hi) {
                t.push((a, b, -c));
                t.push((b, a, -c));
            }
        }
        for c in self.inactive() {
            t.push((c, c, 1.0));
        }
        t.sort_by_key(|e| (e.0, e.1));
        let mut merged: Vec<(usize, usize, T)> = Vec::with_capacity(t.len());
        let mut k = 0;
        while k < t.len() {
            let (r, c) = (t[k].0, t[k].1);
            let mut v = 0.0;
            while k < t.len() && (t[k].0, t[k].1) == (r, c) {
                v += t[k].2;
                k += 1;
            }
            if v != 0.0 || r == c {
                merged.push((r, c, T::from_f64(v)));
            }
        }
        Some(merged)
    }
}

/// The pressure operator of a [`MacGrid`]: H1's 5-point stencil where it is the
/// same matrix, else the face-weighted operator. Both are `A = −D G`.
#[derive(Debug, Clone, PartialEq)]
pub enum PressureOperator {
    /// [`Laplacian2::negative`] (no mask; closed or periodic boundaries).
    Stencil(Laplacian2),
    /// [`MacPoisson`] (masks, open boundaries).
    Faces(MacPoisson),
}

macro_rules! delegate {
    ($self:ident, $op:ident => $e:expr) => {
        match $self {
            PressureOperator::Stencil($op) => $e,
            PressureOperator::Faces($op) => $e,
        }
    };
}

impl<T: Real> LinearOperator<T> for PressureOperator {
    fn name(&self) -> &str {
        delegate!(self, a => LinearOperator::<T>::name(a))
    }
    fn input_shape(&self) -> &[usize] {
        delegate!(self, a => LinearOperator::<T>::input_shape(a))
    }
    fn output_shape(&self) -> &[usize] {
        delegate!(self, a => LinearOperator::<T>::output_shape(a))
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        delegate!(self, a => a.apply_into(x, out))
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        delegate!(self, a => a.apply_transpose_into(y, out))
    }
    fn apply_into_dot(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) -> f64 {
        delegate!(self, a => a.apply_into_dot(x, out))
    }
    fn is_symmetric(&self) -> bool {
        true
    }
    fn diagonal(&self) -> Option<ArrayD<T>> {
        delegate!(self, a => a.diagonal())
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        delegate!(self, a => a.triplets())
    }
}
