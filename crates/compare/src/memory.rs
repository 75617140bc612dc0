//! What a run will allocate, estimated before it allocates, and the memory it
//! may use: a size the machine cannot hold becomes a refused run (a row with
//! [`CompareError::MemoryLimit`]), not an aborted process.
//!
//! The estimates are deliberately rough upper-ish bounds from the grid size:
//!
//! - every scene holds its fields (`b`, the target, the solution, the gradient
//!   and the solver's work vectors): [`SCENE_ARRAYS`] arrays of `n²` values;
//! - the naive tape keeps about seven grid arrays per unrolled CG iteration
//!   ([`crate::harness::naive_bytes_per_iteration`]);
//! - the sparse Cholesky factor of the 5-point Laplacian on an `n × n` grid has,
//!   under nested dissection, about `(31/4) n² log₂ n` entries (George 1973); we
//!   count `8 n² log₂ n` entries of a value and an index each, plus the matrix.
//!
//! # References
//! - A. George, "Nested dissection of a regular finite element mesh", SIAM J.
//!   Numer. Anal. 10 (1973).

use crate::{CompareError, Result};

/// Grid arrays every run of a scene holds besides its method's own storage.
pub const SCENE_ARRAYS: usize = 12;

/// The budget used when `/proc/meminfo` cannot be read: 4 GiB.
pub const FALLBACK_AVAILABLE_BYTES: usize = 4 << 30;

/// Which storage a run needs on top of its scene's fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    /// Only the fields (the implicit method, the straightforward CG).
    Fields,
    /// The fields and a tape of `iterations` unrolled CG iterations.
    NaiveTape {
        /// The iterations expected to be recorded.
        iterations: usize,
    },
    /// The fields and a sparse Cholesky factor.
    Cholesky,
}

/// The memory a run may use and where that figure came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryBudget {
    /// Bytes a single run may allocate.
    pub limit_bytes: usize,
    /// `"--memory-limit-mib"`, `"MemAvailable"` or `"fallback"`.
    pub source: &'static str,
}

impl MemoryBudget {
    /// `limit_mib` MiB if given, else the kernel's `MemAvailable`, else
    /// [`FALLBACK_AVAILABLE_BYTES`].
    pub fn new(limit_mib: Option<usize>) -> Self {
        match limit_mib {
            Some(mib) => MemoryBudget {
                limit_bytes: mib.saturating_mul(1 << 20),
                source: "--memory-limit-mib",
            },
            None => match available_bytes() {
                Some(limit_bytes) => MemoryBudget {
                    limit_bytes,
                    source: "MemAvailable",
                },
                None => MemoryBudget {
                    limit_bytes: FALLBACK_AVAILABLE_BYTES,
                    source: "fallback",
                },
            },
        }
    }

    /// `Ok` if a run of `method` on an `n × n` grid with `value_bytes`-byte
    /// scalars and `storage` fits, else [`CompareError::MemoryLimit`] naming the
    /// size, the method and the estimate.
    ///
    /// # Errors
    /// [`CompareError::MemoryLimit`].
    pub fn check(
        &self,
        method: &str,
        n: usize,
        value_bytes: usize,
        storage: Storage,
    ) -> Result<()> {
        let estimate = estimate_bytes(n, value_bytes, storage);
        if estimate <= self.limit_bytes {
            return Ok(());
        }
        Err(CompareError::MemoryLimit {
            method: method.to_string(),
            n,
            estimate_bytes: estimate,
            limit_bytes: self.limit_bytes,
            source_of_limit: self.source.to_string(),
        })
    }
}

/// The kernel's `MemAvailable` in bytes, if `/proc/meminfo` says.
pub fn available_bytes() -> Option<usize> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: usize = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// Entries of the sparse Cholesky factor of the 5-point Laplacian on `n × n`
/// cells (nested dissection, `8 n² log₂ n`, at least the matrix's `5 n²`).
pub fn cholesky_entries(n: usize) -> usize {
    let cells = (n as f64) * (n as f64);
    let fill = 8.0 * cells * (n.max(2) as f64).log2();
    saturating(fill.max(5.0 * cells))
}

/// Estimated bytes of one run (see the module docs); saturates instead of
/// overflowing, so absurd sizes compare as absurd.
pub fn estimate_bytes(n: usize, value_bytes: usize, storage: Storage) -> usize {
    let cells = n.saturating_mul(n);
    let array = cells.saturating_mul(value_bytes);
    let fields = array.saturating_mul(SCENE_ARRAYS);
    let own = match storage {
        Storage::Fields => 0,
        Storage::NaiveTape { iterations } => iterations.saturating_mul(7).saturating_mul(array),
        // A value (f64) and a row index per entry, plus the matrix itself.
        Storage::Cholesky => cholesky_entries(n)
            .saturating_mul(16)
            .saturating_add(cells.saturating_mul(5 * 16)),
    };
    fields.saturating_add(own)
}

fn saturating(x: f64) -> usize {
    if x >= usize::MAX as f64 {
        usize::MAX
    } else {
        x as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn estimates_grow_with_the_grid_and_refuse_what_does_not_fit() {
        // 100000² cells of f64: b alone is 8e10 bytes.
        let huge = estimate_bytes(100_000, 8, Storage::Fields);
        assert!(huge >= 80_000_000_000);
        let budget = MemoryBudget::new(Some(64));
        assert!(budget.check("implicit", 32, 8, Storage::Fields).is_ok());
        let e = budget
            .check("exact", 100_000, 8, Storage::Cholesky)
            .unwrap_err();
        let text = e.to_string();
        assert!(text.contains("100000") && text.contains("exact"), "{text}");
        assert_eq!(
            estimate_bytes(usize::MAX, 8, Storage::NaiveTape { iterations: 10 }),
            usize::MAX
        );
    }
}
