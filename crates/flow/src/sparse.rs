//! A compressed-row sparse matrix of `f64`, for the stencils a scene assembles once.

use diffphys_tape::parallel;

/// Rows of `(column, value)` pairs.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct Csr {
    pub(crate) rows: usize,
    pub(crate) cols: usize,
    pub(crate) indptr: Vec<usize>,
    pub(crate) indices: Vec<usize>,
    pub(crate) values: Vec<f64>,
}

impl Csr {
    /// From `(row, column, value)` triplets; duplicates are summed.
    pub(crate) fn from_triplets(rows: usize, cols: usize, mut t: Vec<(usize, usize, f64)>) -> Self {
        t.sort_by_key(|e| (e.0, e.1));
        let mut indptr = vec![0; rows + 1];
        let mut indices = Vec::with_capacity(t.len());
        let mut values: Vec<f64> = Vec::with_capacity(t.len());
        let mut last: Option<(usize, usize)> = None;
        for (r, c, v) in t {
            if last == Some((r, c)) {
                *values.last_mut().expect("a previous entry") += v;
                continue;
            }
            last = Some((r, c));
            indices.push(c);
            values.push(v);
            indptr[r + 1] += 1;
        }
        for r in 0..rows {
            indptr[r + 1] += indptr[r];
        }
        Csr {
            rows,
            cols,
            indptr,
            indices,
            values,
        }
    }

    /// `y += alpha · A x`, rows in blocks on all cores for a large matrix
    /// (each row's sum in column order wherever it runs: the same bits on any
    /// number of threads).
    pub(crate) fn mul_add(&self, alpha: f64, x: &[f64], y: &mut [f64]) {
        if self.values.is_empty() {
            return;
        }
        let rows = self.rows.min(y.len());
        parallel::for_each_chunk_mut(&mut y[..rows], |off, block| {
            for (i, yr) in block.iter_mut().enumerate() {
                let r = off + i;
                let mut acc = 0.0;
                for k in self.indptr[r]..self.indptr[r + 1] {
                    acc += self.values[k] * x[self.indices[k]];
                }
                *yr += alpha * acc;
            }
        });
    }

    /// `y += alpha · Aᵀ x`.
    pub(crate) fn mul_t_add(&self, alpha: f64, x: &[f64], y: &mut [f64]) {
        if self.values.is_empty() {
            return;
        }
        for (r, &xr) in x.iter().enumerate().take(self.rows) {
            if xr == 0.0 {
                continue;
            }
            for k in self.indptr[r]..self.indptr[r + 1] {
                y[self.indices[k]] += alpha * self.values[k] * xr;
            }
        }
    }

    /// The diagonal (zero where a row holds none).
    pub(crate) fn diagonal(&self) -> Vec<f64> {
        let mut d = vec![0.0; self.rows];
        for (r, dr) in d.iter_mut().enumerate() {
            for k in self.indptr[r]..self.indptr[r + 1] {
                if self.indices[k] == r {
                    *dr += self.values[k];
                }
            }
        }
        d
    }

    /// All entries as triplets.
    pub(crate) fn triplets(&self) -> Vec<(usize, usize, f64)> {
        let mut t = Vec::with_capacity(self.values.len());
        for r in 0..self.rows {
            for k in self.indptr[r]..self.indptr[r + 1] {
                t.push((r, self.indices[k], self.values[k]));
            }
        }
        t
    }
}
