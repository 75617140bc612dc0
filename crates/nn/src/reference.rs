//! Reference compositions of tape primitives for the fused layer ops: the chain
//! a fused op replaces, used by the tests (same values and gradients) and the
//! benchmarks (time and tape bytes against the op).

use diffphys_tape::{Real, Result, TapeError, Var};

use crate::conv::Padding;

/// `y[i] = x̃[i + s]` along `axis` (of length `n`) with the padding rule:
/// a roll for periodic fields, pad-and-slice for zero padding.
fn shifted<'t, T: Real>(
    x: Var<'t, T>,
    axis: usize,
    s: isize,
    padding: Padding,
) -> Result<Var<'t, T>> {
    if s == 0 {
        return Ok(x);
    }
    match padding {
        Padding::Periodic => x.roll(-s, axis),
        Padding::Zero => {
            let n = x.shape()[axis];
            let r = s.unsigned_abs();
            let start = (r as isize + s) as usize;
            x.pad(axis, r, r)?.slice(axis, start, start + n)
        }
    }
}

/// The convolution of [`crate::conv`] from primitives: for each kernel tap
/// `(p, q)`, the shifted input (roll or pad + slice) times the tap's weights
/// broadcast over `[batch, c_out, c_in, …]`, summed over `c_in`, accumulated
/// with `add`; then the bias. `x` is `[B, C_in, H, W]` (or `[B, C_in, N]`), `w`
/// `[C_out, C_in, K_y, K_x]` (or `[C_out, C_in, K]`), `bias` `[C_out]`.
///
/// # Errors
/// [`TapeError::InvalidArgument`] for ranks other than 3 or 4; whatever the
/// primitives return.
pub fn conv_from_primitives<'t, T: Real>(
    x: Var<'t, T>,
    w: Var<'t, T>,
    bias: Var<'t, T>,
    padding: Padding,
) -> Result<Var<'t, T>> {
    let xs = x.shape();
    let ws = w.shape();
    let rank = xs.len();
    if !(3..=4).contains(&rank) || ws.len() != rank {
        return Err(TapeError::invalid(
            "conv_from_primitives",
            format!("input {xs:?} and kernel {ws:?} must both be 3-D or 4-D"),
        ));
    }
    let (c_out, c_in) = (ws[0], ws[1]);
    let kernel = &ws[2..];
    let spatial = &xs[2..];
    // [B, 1, C_in, spatial…] and per tap [1, C_out, C_in, 1…].
    let mut x_shape = vec![xs[0], 1, c_in];
    x_shape.extend_from_slice(spatial);
    let mut w_shape = vec![1, c_out, c_in];
    w_shape.extend(std::iter::repeat_n(1, rank - 2));
    let taps: Vec<Vec<usize>> = if rank == 3 {
        (0..kernel[0]).map(|q| vec![q]).collect()
    } else {
        (0..kernel[0])
            .flat_map(|p| (0..kernel[1]).map(move |q| vec![p, q]))
            .collect()
    };
    let mut acc: Option<Var<'t, T>> = None;
    for tap in taps {
        let mut shifted_x = x;
        let mut w_tap = w;
        for (d, &t) in tap.iter().enumerate() {
            let axis = 2 + d;
            let s = t as isize - (kernel[d] / 2) as isize;
            shifted_x = shifted(shifted_x, axis, s, padding)?;
            w_tap = w_tap.slice(axis, t, t + 1)?;
        }
        let term = shifted_x
            .reshape(&x_shape)?
            .mul(w_tap.reshape(&w_shape)?)?
            .sum_axis(2)?;
        acc = Some(match acc {
            Some(a) => a.add(term)?,
            None => term,
        });
    }
    let mut b_shape = vec![1, c_out];
    b_shape.extend(std::iter::repeat_n(1, rank - 2));
    acc.expect("at least one tap").add(bias.reshape(&b_shape)?)
}
