//! Study 6: long unrolls of upwind advection at Courant numbers below and
//! above 1.

use diffphys_ops::advection::{AdvectionParams, Upwind1};
use diffphys_ops::{Boundary, Grid1, OpsError};
use diffphys_tape::{Real, Tape, TapeError, Var};
use ndarray::Array1;

use crate::model::Precision;
use crate::progress::Progress;
use crate::{CompareError, Result};

use super::{norm, StabilityConfig, UnrollRow};

/// Where in an unroll a non-finite gradient began: the latest step whose input
/// received a non-finite gradient (reverse mode visits the last step first),
/// found by sweeping again with the check off.
fn locate_unroll_failure<T: Real>(
    tape: &Tape<T>,
    loss: Var<'_, T>,
    step_inputs: &[Var<'_, T>],
) -> Option<usize> {
    tape.set_check_finite(false);
    let grads = tape.backward(loss, step_inputs);
    tape.set_check_finite(true);
    let grads = grads.ok()?;
    step_inputs.iter().rposition(|&v| {
        grads
            .get(v)
            .is_some_and(|g| g.iter().any(|x| !x.is_finite()))
    })
}

/// The scene of the unroll: `n` periodic cells on `[0, 1)`, the velocity
/// `u = 1 + 0.2 sin 2πx` (so the local Courant number stays within a factor
/// 1.5 of the largest: above 1 everywhere when the largest is 1.5), a Gaussian pulse `d⁰` at `x = 0.3` and the target `d*` at
/// `x = 0.6`; the time step gives Courant number `cfl`.
fn unroll_scene(n: usize, cfl: f64) -> Result<(Grid1, AdvectionParams, [Array1<f64>; 3])> {
    let grid = Grid1::new(n, 1.0 / n as f64, 0.0, Boundary::Periodic)?;
    let x = Array1::from_shape_fn(n, |i| (i as f64 + 0.5) / n as f64);
    let u = x.mapv(|x| 1.0 + 0.2 * (2.0 * std::f64::consts::PI * x).sin());
    let pulse = |c: f64| x.mapv(|x| (-(x - c).powi(2) / 0.005).exp());
    let u_max = u.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let mut params = AdvectionParams::new(cfl * grid.dx / u_max);
    // At exactly 1 the computed Courant number may round above 1.
    if cfl >= 1.0 {
        params = params.allowing_cfl_violation();
    }
    Ok((grid, params, [pulse(0.3), u, pulse(0.6)]))
}

/// Study 6, one run: `L = ½‖d_N − d*‖²` after `steps` upwind steps of the
/// unroll's scene (`n` periodic cells, `u = 1 + 0.2 sin 2πx`, a Gaussian pulse
/// `d⁰` at `x = 0.3`, the target `d*` at `x = 0.6`, largest Courant number
/// `cfl`), recorded on the tape, and the norms of `∂L/∂d⁰` and `∂L/∂u`.
///
/// # Errors
/// [`CompareError::UnrollStep`] naming the step and the op (a non-finite value
/// in the forward or the backward of `upwind_1d`, or of the loss); setup errors.
pub fn unroll_gradient<T: Real>(n: usize, cfl: f64, steps: usize) -> Result<(f64, f64, f64)> {
    let (grid, params, [d0, u, target]) = unroll_scene(n, cfl)?;
    let tape = Tape::<T>::new();
    let d0 = tape.var(d0.mapv(T::from_f64).into_dyn());
    let u = tape.var(u.mapv(T::from_f64).into_dyn());
    let target = tape.constant(target.mapv(T::from_f64).into_dyn());
    let mut d = d0;
    let mut step_inputs = Vec::with_capacity(steps + 1);
    for step in 0..steps {
        step_inputs.push(d);
        d = tape
            .apply(Upwind1::new(grid, params), &[d, u])
            .map_err(|e| CompareError::UnrollStep {
                step,
                source: OpsError::Tape(e),
            })?;
    }
    step_inputs.push(d);
    let loss = (|| {
        let r = d.sub(target)?;
        r.dot(r)?.mul_scalar(T::from_f64(0.5))
    })()
    .map_err(|e| CompareError::UnrollStep {
        step: steps,
        source: OpsError::Tape(e),
    })?;
    let grads = match tape.backward(loss, &[d0, u]) {
        Ok(g) => g,
        Err(e @ TapeError::NonFinite { .. }) => {
            let step = locate_unroll_failure(&tape, loss, &step_inputs).unwrap_or(steps);
            return Err(CompareError::UnrollStep {
                step,
                source: OpsError::Tape(e),
            });
        }
        Err(e) => return Err(e.into()),
    };
    let g = |v| grads.get(v).map_or(0.0, |a| norm(a.iter().copied()));
    Ok((loss.item()?.as_f64(), g(d0), g(u)))
}

/// Study 6: [`unroll_gradient`] at every step count and Courant number, `f64`
/// and `f32`.
pub fn unroll_study(config: &StabilityConfig, bar: &dyn Progress) -> Vec<UnrollRow> {
    let mut rows = Vec::new();
    for &cfl in &config.cfls {
        for precision in [Precision::F64, Precision::F32] {
            for &steps in &config.unroll_steps {
                bar.set_message(format!("unroll: CFL {cfl} {precision} N={steps}"));
                let result = if precision == Precision::F64 {
                    unroll_gradient::<f64>(config.unroll_n, cfl, steps)
                } else {
                    unroll_gradient::<f32>(config.unroll_n, cfl, steps)
                };
                let mut row = UnrollRow {
                    cfl,
                    steps,
                    precision,
                    loss: None,
                    grad_d0_norm: None,
                    grad_u_norm: None,
                    finite: true,
                    error: None,
                };
                match result {
                    Ok((loss, gd, gu)) => {
                        row.finite = loss.is_finite() && gd.is_finite() && gu.is_finite();
                        row.loss = Some(loss);
                        row.grad_d0_norm = Some(gd);
                        row.grad_u_norm = Some(gu);
                    }
                    Err(e) => {
                        row.finite = !e.is_non_finite();
                        row.error = Some(e.to_string());
                    }
                }
                rows.push(row);
                bar.inc(1);
            }
        }
    }
    rows
}
