//! # diffphys-compare
//!
//! Three ways to get the gradient of a loss through a Poisson solve, measured side
//! by side: naive (CG unrolled on the tape), implicit (one adjoint CG solve) and
//! exact (a sparse Cholesky reference), with the measurement, report and chart
//! machinery of the `diffphys-compare` command.
//!
//! ```
//! use diffphys_compare::harness::relative_error;
//! use diffphys_compare::methods::{exact::ExactCholesky, implicit::ImplicitSolve};
//! use diffphys_compare::methods::{naive::NaiveUnrolled, GradientMethod, Stop};
//! use diffphys_compare::problem::{Problem, ProblemSpec};
//!
//! // p = A⁻¹ b with A = −∇² on 16×16 cells, L = ½‖p − p*‖², gradient wrt b.
//! let problem = Problem::<f64>::new(ProblemSpec::laplacian(16))?;
//! let stop = Stop::Tolerance { rtol: 1e-10, max_iters: 1000 };
//! let exact = ExactCholesky.run(&problem, stop)?.gradient;
//! let naive = NaiveUnrolled::default().run(&problem, stop)?;
//! let implicit = ImplicitSolve.run(&problem, stop)?;
//! assert!(relative_error(&naive.gradient, &exact).unwrap() < 1e-8);
//! assert!(relative_error(&implicit.gradient, &exact).unwrap() < 1e-8);
//! // The naive tape holds every iterate; the implicit one only b, p and the loss.
//! assert!(implicit.tape_bytes * 20 < naive.tape_bytes);
//! # Ok::<(), diffphys_compare::CompareError>(())
//! ```
#![warn(missing_docs)]

pub mod alloc;
#[cfg(feature = "cli")]
pub mod cli;
mod error;
pub mod harness;
pub mod memory;
pub mod methods;
pub mod model;
pub mod problem;
pub mod report;
pub mod stability;

pub use diffphys_report::{chart, format, npy, progress};
pub use error::{CompareError, Result};
