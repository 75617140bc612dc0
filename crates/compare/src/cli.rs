//! What the command line needs beyond the library: the progress bar of
//! [`diffphys_report`], re-exported where the harness has always offered it.

pub use diffphys_report::progress_bar;
