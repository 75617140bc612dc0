//! The three data splits of the protocol (train, validation, held-out), in
//! a module of their own so that the error type can name one without
//! importing the data layer.

use std::fmt;

/// One of the three data splits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Split {
    /// Fits the parameters.
    Train,
    /// Makes every choice: early stopping, learning rate, unroll length.
    Validation,
    /// Read once per trained model, after selection; reported.
    HeldOut,
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Split::Train => "train",
            Split::Validation => "validation",
            Split::HeldOut => "held-out",
        })
    }
}
