//! The V-cycle: pre-smoothing, the restricted residual, the coarse
//! correction (recursively, down to a dense Cholesky solve of the coarsest
//! level), prolongation and post-smoothing, over one workspace of level
//! vectors allocated once.

use diffphys_tape::{PerPrecision, Real};

use super::hierarchy::Level;
use super::Multigrid;
use crate::{OpsError, Result};

/// The dense Cholesky factor `L` (row-major, lower) of the coarsest level's
/// matrix, with the rows of vanishing pivots dropped (their unknowns set to
/// 0): `x = A_live⁻¹ b` on the other cells, a symmetric generalised inverse.
#[derive(Debug, Clone)]
pub(super) struct CoarseSolve {
    n: usize,
    l: Vec<f64>,
    /// `1/L_jj`, 0 for a dropped pivot.
    inv_pivot: Vec<f64>,
}

impl CoarseSolve {
    pub(super) fn new(level: &Level) -> Result<Self> {
        let n = level.cells();
        let mut a = vec![0.0f64; n * n];
        let mut e = vec![0.0; n];
        let mut col = vec![0.0; n];
        let zero = vec![0.0; n];
        for c in 0..n {
            e[c] = 1.0;
            level.residual(&e, &zero, &mut col);
            for r in 0..n {
                a[r * n + c] = -col[r];
            }
            e[c] = 0.0;
        }
        if level.widths[0].first().is_some_and(|&w| w > 1.0) {
            // No correction on the inactive cells of a coarse level.
            for k in (0..n).filter(|&k| !level.is_active(k)) {
                a[k * n + k] = 0.0;
            }
        }
        let mut inv_pivot = vec![0.0; n];
        for j in 0..n {
            let scale = a[j * n + j];
            let mut d = scale;
            for k in 0..j {
                d -= a[j * n + k] * a[j * n + k];
            }
            if d.is_nan() {
                return Err(OpsError::invalid(
                    "multigrid",
                    format!("non-finite coarsest level ({n} cells)"),
                ));
            }
            if d <= 1e-10 * scale.abs() {
                // A (numerically) singular direction: drop the pivot.
                for i in j..n {
                    a[i * n + j] = 0.0;
                }
                continue;
            }
            let d = d.sqrt();
            a[j * n + j] = d;
            inv_pivot[j] = 1.0 / d;
            for i in j + 1..n {
                let mut s = a[i * n + j];
                for k in 0..j {
                    s -= a[i * n + k] * a[j * n + k];
                }
                a[i * n + j] = s / d;
            }
        }
        Ok(CoarseSolve { n, l: a, inv_pivot })
    }

    fn solve(&self, b: &[f64], x: &mut [f64], y: &mut [f64]) {
        let n = self.n;
        y[..n].copy_from_slice(&b[..n]);
        for i in 0..n {
            let row = &self.l[i * n..i * n + i];
            let s = y[i] - row.iter().zip(&y[..i]).map(|(l, v)| l * v).sum::<f64>();
            y[i] = s * self.inv_pivot[i];
        }
        for i in (0..n).rev() {
            let s = y[i] - (i + 1..n).map(|k| self.l[k * n + i] * y[k]).sum::<f64>();
            y[i] = s * self.inv_pivot[i];
        }
        for (o, &v) in x.iter_mut().zip(y.iter()) {
            *o = v;
        }
    }
}

/// Removes the mean over the active cells (all if `active` is `None`).
pub(super) fn project_mean(v: &mut [f64], active: Option<&[bool]>) {
    let (sum, count) = match active {
        None => (v.iter().sum::<f64>(), v.len()),
        Some(a) => v
            .iter()
            .zip(a)
            .filter(|(_, &a)| a)
            .fold((0.0, 0), |(s, c), (x, _)| (s + x, c + 1)),
    };
    if count == 0 {
        return;
    }
    let mean = sum / count as f64;
    match active {
        None => v.iter_mut().for_each(|x| *x -= mean),
        Some(a) => v
            .iter_mut()
            .zip(a)
            .filter(|(_, &a)| a)
            .for_each(|(x, _)| *x -= mean),
    }
}

/// The vectors of one application of the cycle.
#[derive(Debug, Default)]
pub(super) struct Workspace {
    /// Right-hand side and correction of each coarse level (index `l − 1`).
    coarse: Vec<(Vec<f64>, Vec<f64>)>,
    /// The input and the output of the finest level, in f64 (for `T ≠ f64`).
    input: Vec<f64>,
    output: Vec<f64>,
    /// The mean-free input (singular operator).
    projected: Vec<f64>,
    /// A fine row and a coarse row.
    row: Vec<f64>,
    tmp: Vec<f64>,
    /// The parallel transfers' rows, one lane per block (grown on first use).
    lanes: Vec<f64>,
    /// The coarsest solve's vector.
    y: Vec<f64>,
}

impl Multigrid {
    /// The level vectors of one application, allocated.
    pub(super) fn workspace(&self) -> Workspace {
        let coarse = self.levels[1..]
            .iter()
            .map(|l| (vec![0.0; l.cells()], vec![0.0; l.cells()]))
            .collect();
        let ny = self.levels[0].ny;
        Workspace {
            coarse,
            input: Vec::new(),
            output: Vec::new(),
            projected: if self.singular {
                vec![0.0; self.levels[0].cells()]
            } else {
                Vec::new()
            },
            row: vec![0.0; ny],
            tmp: vec![0.0; ny.div_ceil(2)],
            lanes: Vec::new(),
            y: vec![0.0; self.coarse.n],
        }
    }

    /// `z = B r`: one V-cycle from a zero guess, on slices of the grid's
    /// size. The cycle computes in f64: `f64` vectors are used in place,
    /// `f32` ones through f64 copies.
    pub(super) fn apply_cycle<T: Real>(&self, r: &[T], z: &mut [T]) {
        let apply =
            T::pick::<ApplyFn>(Multigrid::apply_converted::<f32>, Multigrid::apply_in_place);
        apply(self, r, z);
    }

    /// Runs `f` with the cycle's workspace, or with a fresh one if it is busy
    /// (another thread applying the same cycle) or poisoned.
    fn with_workspace(&self, f: impl FnOnce(&mut Workspace)) {
        match self.work.try_lock() {
            Ok(mut work) => f(&mut work),
            Err(_) => f(&mut self.workspace()),
        }
    }

    fn apply_in_place(&self, r: &[f64], z: &mut [f64]) {
        self.with_workspace(|work| self.apply_f64(r, z, work));
    }

    fn apply_converted<T: Real>(&self, r: &[T], z: &mut [T]) {
        self.with_workspace(|work| self.apply_with(r, z, work));
    }

    fn apply_with<T: Real>(&self, r: &[T], z: &mut [T], work: &mut Workspace) {
        let mut input = std::mem::take(&mut work.input);
        let mut output = std::mem::take(&mut work.output);
        input.clear();
        input.extend(r.iter().map(|v| v.as_f64()));
        output.resize(r.len(), 0.0);
        self.apply_f64(&input, &mut output, work);
        for (d, &s) in z.iter_mut().zip(output.iter()) {
            *d = T::from_f64(s);
        }
        work.input = input;
        work.output = output;
    }

    /// `z = B r` in f64 (`r` copied only to remove its mean, if singular).
    fn apply_f64(&self, r: &[f64], z: &mut [f64], work: &mut Workspace) {
        let active = self.levels[0].active.as_deref();
        let Workspace {
            coarse,
            projected,
            row,
            tmp,
            lanes,
            y,
            ..
        } = work;
        let mut scratch = Scratch { row, tmp, lanes, y };
        if self.singular {
            projected.copy_from_slice(r);
            project_mean(projected, active);
            self.cycle(0, projected, z, coarse, &mut scratch);
            project_mean(z, active);
        } else {
            self.cycle(0, r, z, coarse, &mut scratch);
        }
    }

    fn cycle(
        &self,
        l: usize,
        b: &[f64],
        x: &mut [f64],
        coarse: &mut [(Vec<f64>, Vec<f64>)],
        scratch: &mut Scratch<'_>,
    ) {
        if l + 1 == self.levels.len() {
            self.coarse.solve(b, x, scratch.y);
            return;
        }
        let level = &self.levels[l];
        let (tx, ty) = &self.transfers[l];
        x.fill(0.0);
        for _ in 0..self.sweeps {
            level.sweep(x, b, false);
        }
        let ((bc, xc), rest) = coarse.split_first_mut().expect("a coarse level");
        level.restrict_residual(x, b, (tx, ty), bc, scratch.row, scratch.tmp, scratch.lanes);
        self.cycle(l + 1, bc, xc, rest, scratch);
        level.prolong_add(xc, (tx, ty), x, scratch.tmp, scratch.lanes);
        for _ in 0..self.sweeps {
            level.sweep(x, b, true);
        }
    }
}

/// Row buffers and the coarsest vector, borrowed from the workspace.
struct Scratch<'a> {
    row: &'a mut Vec<f64>,
    tmp: &'a mut Vec<f64>,
    lanes: &'a mut Vec<f64>,
    y: &'a mut Vec<f64>,
}

/// `fn(&Multigrid, &[T], &mut [T])`, one per precision: the typed choice of
/// [`Multigrid::apply_cycle`] between the in-place and the converting path.
struct ApplyFn;

impl PerPrecision for ApplyFn {
    type Of<T: Real> = fn(&Multigrid, &[T], &mut [T]);
}
