//! Small helpers of training loops.

use diffphys_tape::{ArrayD, IxDyn, Real};

use crate::{NnError, Result};

/// Passes a finite loss through; a NaN or infinite one stops training with an
/// error naming the step (so no non-finite update ever reaches the parameters).
///
/// # Errors
/// [`NnError::NonFiniteLoss`].
pub fn check_loss(step: usize, loss: f64) -> Result<f64> {
    if loss.is_finite() {
        Ok(loss)
    } else {
        Err(NnError::NonFiniteLoss { step, loss })
    }
}

/// Stacks samples of one shape along a new leading batch axis.
///
/// # Errors
/// [`NnError::Config`] if there are no samples or their shapes differ.
pub fn stack<T: Real>(samples: &[&ArrayD<T>]) -> Result<ArrayD<T>> {
    let Some(first) = samples.first() else {
        return Err(NnError::Config {
            layer: "stack".into(),
            message: "no samples".into(),
        });
    };
    let mut shape = vec![samples.len()];
    shape.extend_from_slice(first.shape());
    let mut data = Vec::with_capacity(shape.iter().product());
    for s in samples {
        if s.shape() != first.shape() {
            return Err(NnError::Config {
                layer: "stack".into(),
                message: format!("sample of shape {:?} among {:?}", s.shape(), first.shape()),
            });
        }
        data.extend(s.iter().copied());
    }
    Ok(ArrayD::from_shape_vec(IxDyn(&shape), data).expect("sizes match"))
}
