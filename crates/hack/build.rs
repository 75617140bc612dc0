//! Empty: cargo uses a package's build-dependencies only when it has a build
//! script, and the host-side features listed there are this crate's purpose.
fn main() {}
