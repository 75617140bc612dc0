//! `wake_flow convergence`: is the reference converged? The reference's
//! scheme at its own resolution ([`FACTOR`]× the coarse one) against the same
//! scheme one level finer (`2 FACTOR`×), both from the same analytic start of
//! each split, both restricted to the coarse grid: the difference, per Re and
//! per step of the recorded window, measured as the held-out errors are (the
//! relative L2 error of the state and of the velocity's deviation from the
//! free stream). Beside it, each level's forces on the body over the window:
//! the mean drag coefficient, the lift's periods (has the shedding settled?)
//! and the Strouhal number from them.

use diffphys::flow::diagnostics::obstacle_force;
use diffphys::flow::validation::Shedding;
use diffphys::flow::{FlowState, Scene};
use diffphys::learn::study::run_jobs;
use diffphys::learn::{DataSeed, Split};
use diffphys::report::progress_bar;
use serde_json::{json, Value};

use super::data::{start_state, Bump};
use super::{
    reference_scene_at, uncorrected, viscosity, Options, Result, Sizes, WakeError, DIAMETER,
    FACTOR, U_IN,
};
use diffphys::flow::PressureSolver;
use diffphys::hybrid::metrics::{deviation_error, velocity_error};
use diffphys::hybrid::reference::{advance, Recorder};

/// One level's recorded window at one Re: the velocities restricted to the
/// coarse grid, and the force coefficients after each coarse step.
struct Window {
    states: Vec<FlowState<f64>>,
    /// `(c_D, c_L)` at each recorded state, `2 F / (U² D)`.
    forces: Vec<[f64; 2]>,
}

/// Views of a sample's fields.
fn views(fields: &[ndarray::ArrayD<f64>]) -> Vec<ndarray::ArrayViewD<'_, f64>> {
    fields.iter().map(|a| a.view()).collect()
}

/// The scenes of one level: its factor and its solver.
struct Level {
    factor: usize,
    fine: Scene,
}

/// `record` coarse steps of `level` at `re` after `warm` from `base`.
fn window(
    sizes: &Sizes,
    coarse: &Scene,
    level: &Level,
    base: &FlowState<f64>,
    re: f64,
    tick: &(dyn Fn(u64) + Sync),
) -> Result<Window> {
    let nu = viscosity(re);
    let scale = 2.0 / (U_IN * U_IN * DIAMETER);
    let mut forces = Vec::new();
    let recorder = Recorder {
        fine: &level.fine,
        coarse,
        factor: level.factor,
        warm: sizes.warm,
        record: sizes.record,
        starts: &[],
    };
    let reference = recorder.record(base, (re, nu), tick, &mut |s| {
        let f = obstacle_force(
            level.fine.force_weights(),
            s.ux.view(),
            s.uy.view(),
            s.pressure.view(),
            nu,
        )?;
        forces.push([scale * f[0], scale * f[1]]);
        Ok(())
    })?;
    Ok(Window {
        states: reference.states,
        forces,
    })
}

/// A level's forces over the window: mean drag, lift amplitude, the lift's
/// periods and the Strouhal number `D / (U T̄)` (null with fewer than two
/// up-crossings).
fn forces_json(w: &Window, dt: f64) -> Value {
    let n = w.forces.len().max(1) as f64;
    let cl = w.forces.iter().map(|f| f[1]);
    let amplitude =
        0.5 * (cl.clone().fold(f64::NEG_INFINITY, f64::max) - cl.fold(f64::INFINITY, f64::min));
    let times: Vec<f64> = (0..w.forces.len()).map(|k| k as f64 * dt).collect();
    let lift: Vec<f64> = w.forces.iter().map(|f| f[1]).collect();
    let shedding = Shedding::of(&times, &lift);
    let strouhal = shedding.strouhal(DIAMETER, U_IN);
    json!({
        "mean_cd": w.forces.iter().map(|f| f[0]).sum::<f64>() / n,
        "cl_amplitude": amplitude,
        "lift_periods": shedding.periods,
        "settled_to_1_percent": shedding.settled(0.01),
        "strouhal": strouhal,
    })
}

/// The convergence check of `options`' train, validation and held-out Re
/// (data seed `data_seed`'s draws), on `options.threads` workers.
///
/// # Errors
/// Whatever the scenes and the solvers return.
pub fn check(options: &Options, sizes: &Sizes, data_seed: u64) -> Result<Value> {
    let coarse = uncorrected(sizes, 1, PressureSolver::Cholesky)?;
    let levels = [FACTOR, 2 * FACTOR]
        .map(|factor| {
            Ok(Level {
                factor,
                fine: reference_scene_at(sizes, factor)?,
            })
        })
        .into_iter()
        .collect::<Result<Vec<_>>>()?;
    let splits = [
        (Split::Train, &options.train_re),
        (Split::Validation, &options.validation_re),
        (Split::HeldOut, &options.held_out_re),
    ];
    let runs: usize = splits.iter().map(|(_, r)| r.len()).sum();
    let bar = progress_bar(
        levels.len() * (splits.len() * sizes.warm_base + runs * (sizes.warm + sizes.record)),
        "reference convergence",
    );
    let tick = |n| bar.inc(n);
    // Each split's base state at each level, from the split's own draw.
    let bases: Vec<(Split, usize, Bump)> = splits
        .iter()
        .flat_map(|&(split, _)| {
            let bump = Bump::draw(&mut DataSeed(data_seed).rng(split));
            (0..levels.len()).map(move |l| (split, l, bump))
        })
        .collect();
    let base_states = run_jobs(&bases, options.threads, |&(_, l, bump)| {
        let fine = &levels[l].fine;
        let start = start_state(fine, bump);
        advance(
            fine,
            levels[l].factor,
            start,
            viscosity(sizes.base_re),
            sizes.warm_base,
            &tick,
        )
    })?;
    let n = levels.len();
    let jobs: Vec<(usize, f64, usize)> = splits
        .iter()
        .enumerate()
        .flat_map(|(i, (_, res))| {
            res.iter()
                .flat_map(move |&re| (0..n).map(move |l| (i, re, l)))
        })
        .collect();
    let windows = run_jobs(&jobs, options.threads, |&(i, re, l)| {
        let base = &base_states[i * levels.len() + l];
        window(sizes, &coarse, &levels[l], base, re, &tick)
    })?;
    bar.finish_and_clear();
    let mut per_re = Vec::new();
    for (pair, level_windows) in jobs.chunks(levels.len()).zip(windows.chunks(levels.len())) {
        let (i, re, _) = pair[0];
        let (ours, finer) = (&level_windows[0], &level_windows[1]);
        let steps = 1..ours.states.len();
        let state: f64 = steps
            .clone()
            .map(|t| {
                let s = &ours.states[t];
                velocity_error((&s.ux, &s.uy), &finer.states[t])
            })
            .sum::<f64>()
            / steps.len() as f64;
        let deviation: f64 = steps
            .clone()
            .map(|t| {
                let (p, r) = (
                    coarse.sample_of(&ours.states[t]),
                    coarse.sample_of(&finer.states[t]),
                );
                deviation_error(&coarse, [U_IN, 0.0], &views(&p), &views(&r))
            })
            .sum::<f64>()
            / steps.len() as f64;
        if !(state.is_finite() && deviation.is_finite()) {
            return Err(WakeError::Output(format!(
                "the reference at Re {re} and one level finer differ by a non-finite amount"
            )));
        }
        println!(
            "  {:?} Re {re:>6}: reference against one level finer, state {state:.4}, deviation {deviation:.4}",
            splits[i].0
        );
        per_re.push(json!({
            "split": format!("{:?}", splits[i].0),
            "re": re,
            "state_difference": state,
            "deviation_difference": deviation,
            format!("forces_{}x", levels[0].factor): forces_json(ours, sizes.dt),
            format!("forces_{}x", levels[1].factor): forces_json(finer, sizes.dt),
        }));
    }
    Ok(json!({
        "data_seed": data_seed,
        "levels": levels.iter().map(|l| [l.fine.grid().ny, l.fine.grid().nx]).collect::<Vec<_>>(),
        "recorded_steps": sizes.record,
        "per_re": per_re,
    }))
}
