//! The README and the tutorials as doctests: every ```` ```rust ```` block that
//! is a whole program is compiled and run by `cargo test --doc`; excerpts of
//! examples are marked ` ```rust,ignore ` and checked against the example's
//! source by `tests/docs_excerpts.rs`.

#[doc = include_str!("../README.md")]
pub struct Readme;

#[doc = include_str!("../docs/01-tape-and-custom-ops.md")]
pub struct TapeAndCustomOps;

#[doc = include_str!("../docs/02-advection-inverse-problems.md")]
pub struct AdvectionInverseProblems;

#[doc = include_str!("../docs/03-implicit-gradients.md")]
pub struct ImplicitGradients;

#[doc = include_str!("../docs/04-naive-vs-implicit.md")]
pub struct NaiveVsImplicit;

#[doc = include_str!("../docs/05-stability.md")]
pub struct Stability;

#[doc = include_str!("../docs/06-training-through-the-solver.md")]
pub struct TrainingThroughTheSolver;

#[doc = include_str!("../docs/07-solver-in-the-loop.md")]
pub struct SolverInTheLoop;

#[doc = include_str!("../docs/08-performance.md")]
pub struct Performance;

#[doc = include_str!("../docs/09-from-another-engine.md")]
pub struct FromAnotherEngine;

#[doc = include_str!("../docs/10-flow.md")]
pub struct Flow;

#[doc = include_str!("../docs/11-wake-flow.md")]
pub struct WakeFlow;
