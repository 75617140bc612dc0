//! Feature unification for the diffphys workspace, and nothing else.
//!
//! Every workspace member depends on this crate, and this crate depends on the
//! third-party crates whose features would otherwise differ between cargo
//! commands (see its `Cargo.toml`). The test command, the comparison harness
//! and every example then share one build of the dependencies.
#![warn(missing_docs)]
