//! The measurements of `wake_flow` beyond training: held-out rollouts, the
//! speed-against-accuracy study, the pressure solves, the capacity table and
//! the charts.

use std::path::Path;
use std::time::Instant;

use diffphys::flow::{FlowParams, FlowState, PressureSolver};
use diffphys::hybrid::reference::{evaluate, Evaluation, Rollouts};
use diffphys::hybrid::speed;
use diffphys::learn::{Corrector, Hybrid};
use diffphys::nn::Params;
use ndarray::Array2;
use serde_json::{json, Value};

use super::data::Reference;
use super::{reference_scene_at, uncorrected, viscosity, Coarse, Result, Sizes, FACTOR, U_IN};

/// The rollouts of the hybrid (`params = None`: the coarse solver alone) on
/// one held-out reference ([`evaluate`]): `rollout` steps from each start,
/// and the long rollout from step 0.
///
/// # Errors
/// Whatever the rollouts return.
pub fn held_out_re<C: Corrector + 'static>(
    hybrid: &Hybrid<Coarse, C>,
    params: Option<&Params<f64>>,
    r: &Reference,
    sizes: &Sizes,
) -> Result<Rollouts> {
    let e = Evaluation {
        starts: &sizes.starts,
        rollout: sizes.rollout,
        long: sizes.long,
        free_stream: [U_IN, 0.0],
    };
    Ok(evaluate(hybrid, params, r, &e)?)
}

/// Speed against accuracy on the held-out references: the uncorrected solver
/// at 1×, 2× and 4× the coarse resolution, the reference's scheme at 1×, 2×
/// and 4× (the honest "just run a finer grid"), and the corrected coarse
/// solver (the selected SOL corrector of the first training seed); the chart
/// `speed_accuracy.svg` in `out`.
///
/// # Errors
/// Whatever the solvers return.
pub fn speed<C: Corrector + 'static>(
    hybrid: &Hybrid<Coarse, C>,
    corrector: Option<&Params<f64>>,
    refs: &[Reference],
    sizes: &Sizes,
    out: &Path,
) -> Result<Value> {
    let starts = (&sizes.starts[..], &sizes.speed_starts[..]);
    let cases = speed::cases(refs, starts, FACTOR, sizes.rollout)?;
    let coarse = hybrid.simulator().scene().grid();
    let cells = |level: usize| format!("{} x {}", level * sizes.ny, level * sizes.nx);
    let mut table = speed::Table::default();
    let uncorrected_1 = format!("uncorrected {}", cells(1));
    table.push(&uncorrected_1, 1, speed::corrected(hybrid, None, &cases)?);
    for level in [2, 4] {
        let scene = uncorrected(sizes, level, PressureSolver::Cholesky)?;
        let t = speed::finer(&scene, level, coarse, &cases)?;
        table.push(format!("uncorrected {}", cells(level)), level, t);
    }
    for level in [1, 2, 4] {
        let scene = reference_scene_at(sizes, level)?;
        let t = speed::finer(&scene, level, coarse, &cases)?;
        table.push(format!("reference scheme {}", cells(level)), level, t);
    }
    let verdict = match corrector {
        Some(p) => {
            let c = speed::corrected(hybrid, Some(p), &cases)?;
            table.push(format!("corrected {} (selected SOL)", cells(1)), 1, c);
            let of = |label: String| table.get(&label).map(|r| r.timed);
            let (t, r) = (
                of(format!("uncorrected {}", cells(2))),
                of(format!("reference scheme {}", cells(2))),
            );
            let matched = (table.rows[..3].iter())
                .find(|r| r.timed.rel_error <= c.rel_error)
                .map(|r| r.solver.clone());
            json!({
                "corrected_beats_2x_in_error": t.map(|t| c.rel_error < t.rel_error),
                "corrected_beats_2x_in_time": t.map(|t| c.seconds_per_step < t.seconds_per_step),
                "corrected_beats_reference_scheme_2x_in_error": r.map(|r| c.rel_error < r.rel_error),
                "corrected_beats_reference_scheme_2x_in_time": r.map(|r| c.seconds_per_step < r.seconds_per_step),
                "first_uncorrected_resolution_at_or_below_corrected_error": matched,
            })
        }
        None => Value::Null,
    };
    table.chart(
        &out.join("speed_accuracy.svg"),
        "Held-out error against wall time per step",
    )?;
    Ok(json!({
        "rows": table.rows_json(),
        "verdict": verdict,
        "rollout_steps": sizes.rollout,
        "starts": sizes.speed_starts,
        "note": "wall time per coarse step and sample on this machine (2 cores shared); finer solvers take 2 and 4 substeps per coarse step and start from the reference's fine state restricted to their grid; the reference scheme (MacCormack with the limiter, incremental splitting) starts with a zero pressure",
    }))
}

/// Pressure-solve iterations and time per step inside a rollout: CG with
/// Jacobi from a zero guess and warm-started from the previous step's
/// pressure, and MG-PCG warm-started, at the coarse and the 4× resolution;
/// sparse Cholesky for comparison.
///
/// # Errors
/// Whatever the solvers return.
pub fn pressure_solves(sizes: &Sizes, re: f64) -> Result<Value> {
    let steps = 20;
    let tol = 1e-8;
    let mut out = Vec::new();
    for level in [1, FACTOR] {
        let develop = uncorrected(sizes, level, PressureSolver::Cholesky)?;
        let p = FlowParams {
            viscosity: viscosity(re),
            ..develop.params()
        };
        let g = develop.grid();
        let mut start = FlowState::from_velocity(
            &develop,
            Array2::from_elem(g.shape_x(), 1.0),
            Array2::from_elem(g.shape_y(), 0.0),
        );
        for _ in 0..(40 * level) {
            start = develop.forward(&start, &p)?.0;
        }
        let solvers = [
            ("cholesky", PressureSolver::Cholesky, true),
            (
                "cg_jacobi_zero_guess",
                PressureSolver::Cg {
                    rel_tol: tol,
                    max_iters: 20_000,
                },
                false,
            ),
            (
                "cg_jacobi_warm_start",
                PressureSolver::Cg {
                    rel_tol: tol,
                    max_iters: 20_000,
                },
                true,
            ),
            (
                "mg_pcg_zero_guess",
                PressureSolver::MultigridCg {
                    rel_tol: tol,
                    max_iters: 500,
                    sweeps: 2,
                },
                false,
            ),
            (
                "mg_pcg_warm_start",
                PressureSolver::MultigridCg {
                    rel_tol: tol,
                    max_iters: 500,
                    sweeps: 2,
                },
                true,
            ),
        ];
        for (name, solver, warm) in solvers {
            let scene = uncorrected(sizes, level, solver)?;
            let mut s = start.clone();
            let (mut iters, mut seconds) = (0usize, 0.0);
            for _ in 0..steps {
                if !warm {
                    s.pressure.fill(0.0);
                }
                let t0 = Instant::now();
                let (next, info) = scene.forward(&s, &p)?;
                seconds += t0.elapsed().as_secs_f64();
                iters += info.pressure_iterations.iter().sum::<usize>();
                s = next;
            }
            out.push(json!({
                "grid": [level * sizes.ny, level * sizes.nx],
                "solver": name,
                "iterations_per_step": iters as f64 / steps as f64,
                "ms_per_step": seconds / steps as f64 * 1e3,
            }));
            println!(
                "  pressure {} x {} {name}: {:.1} iterations, {:.2} ms per step",
                level * sizes.ny,
                level * sizes.nx,
                iters as f64 / steps as f64,
                seconds / steps as f64 * 1e3
            );
        }
    }
    Ok(json!({"re": re, "rel_tol": tol, "steps": steps, "rows": out}))
}
