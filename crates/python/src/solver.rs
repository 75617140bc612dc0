//! The solver keyword arguments shared by the Poisson solve and the pressure
//! projection, turned into [`CgParams`].

use std::sync::Arc;

use diffphys_ops::cg::{CgInfo, CgParams, Preconditioning};
use diffphys_ops::multigrid::Multigrid;
use diffphys_tape::Real;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{check, InvalidArgumentError};

/// Which preconditioner CG uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    /// Plain CG.
    None,
    /// Jacobi (`M = diag A`).
    Jacobi,
    /// One multigrid V-cycle per iteration (MG-PCG).
    Multigrid,
}

impl Kind {
    /// By name: `"multigrid"` (or `"mg"`), `"jacobi"` or `"none"`.
    pub(crate) fn parse(name: &str) -> PyResult<Self> {
        match name.to_ascii_lowercase().as_str() {
            "multigrid" | "mg" => Ok(Kind::Multigrid),
            "jacobi" => Ok(Kind::Jacobi),
            "none" | "cg" => Ok(Kind::None),
            other => Err(InvalidArgumentError::new_err(format!(
                "unknown preconditioner {other:?}: use \"multigrid\", \"jacobi\" or \"none\""
            ))),
        }
    }
}

/// The relative tolerance of a solve in f64 unless one is given.
pub(crate) const DEFAULT_REL_TOL_F64: f64 = 1e-10;
/// The relative tolerance of a solve in f32 unless one is given (above the
/// rounding floor of single precision on the grids we solve).
pub(crate) const DEFAULT_REL_TOL_F32: f64 = 1e-5;

/// The CG parameters of the forward and the adjoint solve, per precision.
#[derive(Debug, Clone)]
pub(crate) struct Params {
    single: (CgParams, CgParams),
    double: (CgParams, CgParams),
}

impl Params {
    /// `(forward, adjoint)` for solves in `T`.
    pub(crate) fn of<T: Real>(&self) -> &(CgParams, CgParams) {
        if T::NAME == "f32" {
            &self.single
        } else {
            &self.double
        }
    }

    /// Both precisions' parameters, changed by `f`.
    pub(crate) fn map(self, f: impl Fn(CgParams) -> CgParams) -> Self {
        Params {
            single: (f(self.single.0), f(self.single.1)),
            double: (f(self.double.0), f(self.double.1)),
        }
    }
}

/// The solver's keyword arguments.
#[derive(Debug, Clone)]
pub(crate) struct Options {
    pub(crate) preconditioner: Kind,
    /// `None`: [`DEFAULT_REL_TOL_F64`] in f64, [`DEFAULT_REL_TOL_F32`] in f32.
    pub(crate) rel_tol: Option<f64>,
    pub(crate) abs_tol: f64,
    pub(crate) max_iters: Option<usize>,
    pub(crate) sweeps: usize,
    pub(crate) adjoint_rel_tol: Option<f64>,
    /// Exactly this many iterations in each solve, no tolerance and no error at
    /// the cap ([`CgParams::fixed_iterations`]); excludes the tolerances and
    /// `max_iters`.
    pub(crate) iterations: Option<usize>,
}

impl Options {
    /// The CG parameters of the forward and the adjoint solve in each
    /// precision; `multigrid` builds the cycle when the preconditioner is
    /// multigrid (one cycle serves both precisions and both solves).
    pub(crate) fn params(
        &self,
        multigrid: impl FnOnce(usize) -> diffphys_ops::Result<Multigrid>,
    ) -> PyResult<Params> {
        let tolerances = [
            ("rel_tol", self.rel_tol.unwrap_or(0.0)),
            ("abs_tol", self.abs_tol),
            ("adjoint_rel_tol", self.adjoint_rel_tol.unwrap_or(0.0)),
        ];
        for (name, tol) in tolerances {
            if !(tol >= 0.0 && tol.is_finite()) {
                return Err(InvalidArgumentError::new_err(format!(
                    "{name} must be finite and non-negative, got {tol}"
                )));
            }
        }
        if let Some(k) = self.iterations {
            let given = [
                ("rel_tol", self.rel_tol.is_some()),
                ("abs_tol", self.abs_tol != 0.0),
                ("max_iters", self.max_iters.is_some()),
                ("adjoint_rel_tol", self.adjoint_rel_tol.is_some()),
            ];
            if let Some((name, _)) = given.iter().find(|g| g.1) {
                return Err(InvalidArgumentError::new_err(format!(
                    "iterations={k} runs a fixed number of iterations without a tolerance; \
                     {name} cannot be given with it"
                )));
            }
            if k == 0 {
                return Err(InvalidArgumentError::new_err(
                    "iterations must be at least 1",
                ));
            }
        }
        let mut base = match self.iterations {
            Some(k) => CgParams::default().fixed_iterations(k),
            None => CgParams::default().with_abs_tol(self.abs_tol),
        };
        if let Some(cap) = self.max_iters {
            base = base.with_max_iters(cap);
        }
        base = match self.preconditioner {
            Kind::None => base,
            Kind::Jacobi => base.with_preconditioner(Preconditioning::Jacobi),
            Kind::Multigrid => {
                let mg = Arc::new(check(multigrid(self.sweeps))?);
                base.with_preconditioner(mg)
            }
        };
        let pair = |default: f64| {
            if self.iterations.is_some() {
                return (base.clone(), base.clone());
            }
            let forward = base.clone().with_rel_tol(self.rel_tol.unwrap_or(default));
            let adjoint = forward
                .clone()
                .with_rel_tol(self.adjoint_rel_tol.unwrap_or(forward.rel_tol));
            (forward, adjoint)
        };
        Ok(Params {
            single: pair(DEFAULT_REL_TOL_F32),
            double: pair(DEFAULT_REL_TOL_F64),
        })
    }
}

/// A solve's record as a dict: `iterations`, `relative_residual`, `converged`.
pub(crate) fn info_dict<'py>(py: Python<'py>, info: &CgInfo) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("iterations", info.iterations)?;
    d.set_item("relative_residual", info.relative_residual)?;
    d.set_item("converged", info.converged)?;
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(rel_tol: Option<f64>) -> Options {
        Options {
            preconditioner: Kind::Jacobi,
            rel_tol,
            abs_tol: 0.0,
            max_iters: Some(7),
            sweeps: 2,
            adjoint_rel_tol: Some(1e-6),
            iterations: None,
        }
    }

    #[test]
    fn default_tolerances_follow_the_precision() {
        let no_mg = |_| unreachable!("Jacobi builds no cycle");
        let p = options(None).params(no_mg).unwrap();
        assert_eq!(p.of::<f32>().0.rel_tol, DEFAULT_REL_TOL_F32);
        assert_eq!(p.of::<f64>().0.rel_tol, DEFAULT_REL_TOL_F64);
        assert_eq!(p.of::<f64>().1.rel_tol, 1e-6); // the adjoint's own
        assert_eq!(p.of::<f64>().0.max_iters, Some(7));
        let given = options(Some(1e-3)).params(no_mg).unwrap();
        assert_eq!(given.of::<f32>().0.rel_tol, 1e-3);
    }

    #[test]
    fn bad_names_and_tolerances_are_rejected() {
        assert!(Kind::parse("ilu").is_err());
        assert_eq!(Kind::parse("MG").unwrap(), Kind::Multigrid);
        let no_mg = |_| unreachable!("rejected before");
        assert!(options(Some(-1.0)).params(no_mg).is_err());
        assert!(options(Some(f64::NAN)).params(no_mg).is_err());
    }

    #[test]
    fn fixed_iterations_exclude_tolerances() {
        let no_mg = |_| unreachable!("Jacobi builds no cycle");
        let fixed = |o: Options| Options {
            iterations: Some(5),
            ..o
        };
        // max_iters and adjoint_rel_tol are set by `options`: refused (the
        // message is checked by the Python tests, which have an interpreter).
        assert!(fixed(options(None)).params(no_mg).is_err());
        let plain = Options {
            max_iters: None,
            adjoint_rel_tol: None,
            ..fixed(options(None))
        };
        let p = plain.params(no_mg).unwrap();
        for (forward, adjoint) in [p.of::<f32>(), p.of::<f64>()] {
            for q in [forward, adjoint] {
                assert_eq!((q.max_iters, q.rel_tol), (Some(5), 0.0));
                assert!(!q.require_convergence);
            }
        }
        let zero = Options {
            iterations: Some(0),
            ..plain
        };
        assert!(zero.params(no_mg).is_err());
    }
}
