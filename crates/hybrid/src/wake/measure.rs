//! The measurements of a wake study beyond training: a hybrid's rollouts on
//! one reference, the speed-against-accuracy study and the pressure solves
//! inside a rollout.

use std::path::Path;
use std::time::Instant;

use diffphys_flow::{FlowParams, FlowState, PressureSolver};
use diffphys_learn::{Corrector, Hybrid};
use diffphys_nn::Params;
use ndarray::Array2;
use serde_json::{json, Value};

use super::Wake;
use crate::reference::{evaluate, Evaluation, Reference, Rollouts};
use crate::speed;
use crate::{FlowSimulator, Result};

impl Wake {
    /// How a held-out reference is rolled out: `rollout` steps from each
    /// start, the long rollout from step 0, errors of the deviation from the
    /// inflow.
    pub fn evaluation(&self) -> Evaluation<'_> {
        let s = &self.sizes;
        Evaluation {
            starts: &s.starts,
            rollout: s.rollout,
            long: s.long,
            free_stream: [self.channel.inflow, 0.0],
        }
    }

    /// The rollouts of the hybrid (`params = None`: the coarse solver alone)
    /// on one reference ([`evaluate`] with [`Wake::evaluation`]).
    ///
    /// # Errors
    /// Whatever the rollouts return.
    pub fn rollouts<C: Corrector + 'static>(
        &self,
        hybrid: &Hybrid<FlowSimulator, C>,
        params: Option<&Params<f64>>,
        r: &Reference,
    ) -> Result<Rollouts> {
        evaluate(hybrid, params, r, &self.evaluation())
    }

    /// Speed against accuracy on `refs`: the uncorrected solver at 1×, 2×
    /// and 4× the coarse resolution, the reference's scheme at 1×, 2× and 4×
    /// (the honest "just run a finer grid"), and the corrected coarse solver
    /// (`corrector`, where given); the chart `speed_accuracy.svg` in `out`.
    ///
    /// # Errors
    /// Whatever the solvers return.
    pub fn speed<C: Corrector + 'static>(
        &self,
        hybrid: &Hybrid<FlowSimulator, C>,
        corrector: Option<&Params<f64>>,
        refs: &[Reference],
        out: &Path,
    ) -> Result<Value> {
        let s = &self.sizes;
        let starts = (&s.starts[..], &s.speed_starts[..]);
        let free_stream = [self.channel.inflow, 0.0];
        let cases = speed::cases(refs, starts, self.channel.factor, s.rollout, free_stream)?;
        let coarse = hybrid.simulator().scene().grid();
        let cells = |level: usize| format!("{} x {}", level * s.ny, level * s.nx);
        let mut table = speed::Table::default();
        let uncorrected_1 = format!("uncorrected {}", cells(1));
        table.push(&uncorrected_1, 1, speed::corrected(hybrid, None, &cases)?);
        for level in [2, 4] {
            let scene = self.uncorrected(level, PressureSolver::Cholesky)?;
            let t = speed::finer(&scene, level, coarse, &cases)?;
            table.push(format!("uncorrected {}", cells(level)), level, t);
        }
        for level in [1, 2, 4] {
            let scene = self.reference_scene_at(level)?;
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
                    "corrected_beats_reference_scheme_2x_in_deviation": r.map(|r| c.deviation_error < r.deviation_error),
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
            "rollout_steps": s.rollout,
            "starts": s.speed_starts,
            "note": "wall time per coarse step and sample on this machine (2 cores shared); finer solvers take 2 and 4 substeps per coarse step and start from the reference's fine state restricted to their grid; the reference scheme (MacCormack with the limiter, incremental splitting) starts with a zero pressure",
        }))
    }

    /// Pressure-solve iterations and time per step inside a rollout at `re`:
    /// CG with Jacobi from a zero guess and warm-started from the previous
    /// step's pressure, and MG-PCG from both, at the coarse and the
    /// reference's resolution; sparse Cholesky for comparison.
    ///
    /// # Errors
    /// Whatever the solvers return.
    pub fn pressure_solves(&self, re: f64) -> Result<Value> {
        let (steps, tol) = (20, 1e-8);
        let cg = PressureSolver::Cg {
            rel_tol: tol,
            max_iters: 20_000,
        };
        let mg = PressureSolver::MultigridCg {
            rel_tol: tol,
            max_iters: 500,
            sweeps: 2,
        };
        let solvers = [
            ("cholesky", PressureSolver::Cholesky, true),
            ("cg_jacobi_zero_guess", cg.clone(), false),
            ("cg_jacobi_warm_start", cg, true),
            ("mg_pcg_zero_guess", mg.clone(), false),
            ("mg_pcg_warm_start", mg, true),
        ];
        let s = &self.sizes;
        let mut out = Vec::new();
        for level in [1, self.channel.factor] {
            let develop = self.uncorrected(level, PressureSolver::Cholesky)?;
            let p = FlowParams {
                viscosity: self.channel.viscosity(re),
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
            for (name, solver, warm) in solvers.iter().cloned() {
                let scene = self.uncorrected(level, solver)?;
                let mut state = start.clone();
                let (mut iters, mut seconds) = (0usize, 0.0);
                for _ in 0..steps {
                    if !warm {
                        state.pressure.fill(0.0);
                    }
                    let t0 = Instant::now();
                    let (next, info) = scene.forward(&state, &p)?;
                    seconds += t0.elapsed().as_secs_f64();
                    iters += info.pressure_iterations.iter().sum::<usize>();
                    state = next;
                }
                let (per_step, ms) = (iters as f64 / steps as f64, seconds / steps as f64 * 1e3);
                let (ny, nx) = (level * s.ny, level * s.nx);
                println!(
                    "  pressure {ny} x {nx} {name}: {per_step:.1} iterations, {ms:.2} ms per step"
                );
                out.push(json!({
                    "grid": [ny, nx],
                    "solver": name,
                    "iterations_per_step": per_step,
                    "ms_per_step": ms,
                }));
            }
        }
        Ok(json!({"re": re, "rel_tol": tol, "steps": steps, "rows": out}))
    }
}
