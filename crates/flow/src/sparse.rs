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
    /// From `(row, column, value)` triplets; duplicates are summed, in the
    /// order they come.
    ///
    /// The triplets are bucketed by row (a counting sort, stable) and each
    /// row's few entries then sorted by column (stable): the order of a
    /// stable sort by `(row, column)`, so the same sums, in `O(n)` for
    /// stencils where a global sort of a large grid's triplets dominated a
    /// scene's set-up.
    pub(crate) fn from_triplets(rows: usize, cols: usize, t: Vec<(usize, usize, f64)>) -> Self {
        let t = by_row_then_column(rows, t);
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

/// `t` in the order of a stable sort by `(row, column)`: bucketed by row,
/// each row then sorted by column (both stable).
fn by_row_then_column(rows: usize, t: Vec<(usize, usize, f64)>) -> Vec<(usize, usize, f64)> {
    let mut start = vec![0usize; rows + 1];
    for e in &t {
        start[e.0 + 1] += 1;
    }
    for r in 0..rows {
        start[r + 1] += start[r];
    }
    let mut next = start.clone();
    let mut out = vec![(0, 0, 0.0); t.len()];
    for e in t {
        out[next[e.0]] = e;
        next[e.0] += 1;
    }
    for r in 0..rows {
        out[start[r]..start[r + 1]].sort_by_key(|e| e.1);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bucketing_gives_the_order_of_a_stable_sort() {
        // rows out of order, columns out of order, duplicates with distinct values
        let mut t = Vec::new();
        for i in 0..200usize {
            let (r, c) = ((i * 37) % 13, (i * 11) % 7);
            t.push((r, c, i as f64 * 0.1 + 1.0 / (i as f64 + 3.0)));
        }
        let mut sorted = t.clone();
        sorted.sort_by_key(|e| (e.0, e.1));
        let bucketed = by_row_then_column(13, t.clone());
        let bits = |v: &[(usize, usize, f64)]| -> Vec<(usize, usize, u64)> {
            v.iter().map(|&(r, c, x)| (r, c, x.to_bits())).collect()
        };
        assert_eq!(bits(&bucketed), bits(&sorted));
        let m = Csr::from_triplets(13, 7, t);
        assert_eq!(m.indptr.len(), 14);
        assert_eq!(m.values.len(), m.indices.len());
    }
}
