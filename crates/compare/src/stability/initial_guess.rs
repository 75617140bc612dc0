//! Study 5: the initial guess `x0` (zero implicit gradient, non-zero naive).

use ndarray::Array2;

use crate::methods::implicit::implicit_initial_guess_gradient;
use crate::methods::naive::NaiveUnrolled;
use crate::methods::Stop;
use crate::model::Method;
use crate::problem::{Problem, ProblemSpec};
use crate::progress::Progress;
use crate::{CompareError, Result};

use super::{norm, InitialGuessRow, TOLERANCE_CAP};

/// Study 5: `∂L/∂x0` of both methods, started from a non-zero initial guess, at
/// fixed iteration counts and converged, with a central difference of each
/// method's own loss along a fixed direction of `x0`.
///
/// # Errors
/// As [`iteration_study`](super::iteration_study).
pub fn initial_guess_study(
    n: usize,
    counts: &[usize],
    bar: &dyn Progress,
) -> Result<Vec<InitialGuessRow>> {
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(n))?;
    let to2 = |a: ndarray::ArrayD<f64>| {
        a.into_dimensionality::<ndarray::Ix2>()
            .map_err(|e| CompareError::invalid(format!("x0 study: {e}")))
    };
    // A rough initial guess of the solution's size, and a direction to perturb it.
    let x0 = to2(diffphys_tape::test_array::<f64>(&[n, n], 0x0b5e))? * 0.05;
    let direction = to2(diffphys_tape::test_array::<f64>(&[n, n], 0xd1ec))?;
    let h = 1e-4;
    let mut stops: Vec<Stop> = counts.iter().map(|&k| Stop::Iterations(k)).collect();
    stops.push(Stop::Tolerance {
        rtol: 1e-10,
        max_iters: TOLERANCE_CAP,
    });
    let mut rows = Vec::new();
    for stop in stops {
        for method in [Method::Naive, Method::Implicit] {
            bar.set_message(format!("initial guess: {method} {stop:?}"));
            let run = |x: &Array2<f64>| -> Result<(f64, Array2<f64>, Array2<f64>)> {
                if method == Method::Naive {
                    let (out, g0) = NaiveUnrolled::default().run_from(&problem, stop, Some(x))?;
                    let g0 = g0.ok_or_else(|| CompareError::invalid("naive: no x0 gradient"))?;
                    Ok((out.loss, out.gradient, g0))
                } else {
                    implicit_initial_guess_gradient(&problem, stop, x)
                }
            };
            let mut row = InitialGuessRow {
                method,
                n,
                iterations: match stop {
                    Stop::Iterations(k) => Some(k),
                    Stop::Tolerance { .. } => None,
                },
                rtol: stop.rtol(),
                x0_grad_norm: None,
                b_grad_norm: None,
                x0_grad_exactly_zero: None,
                x0_finite_difference: None,
                x0_directional: None,
                error: None,
            };
            match run(&x0) {
                Ok((_, gb, g0)) => {
                    row.x0_grad_norm = Some(norm(g0.iter().copied()));
                    row.b_grad_norm = Some(norm(gb.iter().copied()));
                    row.x0_grad_exactly_zero = Some(g0.iter().all(|&v| v == 0.0));
                    row.x0_directional = Some((&g0 * &direction).sum());
                    let plus = run(&(&x0 + &(&direction * h)));
                    let minus = run(&(&x0 - &(&direction * h)));
                    if let (Ok(p), Ok(m)) = (plus, minus) {
                        row.x0_finite_difference = Some((p.0 - m.0) / (2.0 * h));
                    }
                }
                Err(e) => row.error = Some(e.to_string()),
            }
            rows.push(row);
            bar.inc(1);
        }
    }
    Ok(rows)
}
