//! `wake_flow convergence`: is the reference converged? The reference's
//! scheme at its own resolution ([`FACTOR`]× the coarse one) against the same
//! scheme one level finer (`2 FACTOR`×), both from the same analytic start of
//! each split, both restricted to the coarse grid: the difference, per Re and
//! per step of the recorded window, measured as the held-out errors are (the
//! relative L2 error of the state and of the velocity's deviation from the
//! free stream). Beside it, each level's forces on the body over the window:
//! the mean drag coefficient, the lift's periods (has the shedding settled?)
//! and the Strouhal number from them.

use diffphys::hybrid::convergence::{Level, Windows};
use diffphys::learn::study::run_jobs;
use diffphys::learn::{DataSeed, Split};
use diffphys::report::progress_bar;
use serde_json::{json, Value};

use super::data::{start_state, Bump};
use super::{
    reference_scene_at, uncorrected, viscosity, Options, Result, Sizes, DIAMETER, FACTOR, U_IN,
};
use diffphys::flow::PressureSolver;
use diffphys::hybrid::reference::advance;

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
    let w = Windows {
        coarse: &coarse,
        warm: sizes.warm,
        record: sizes.record,
        free_stream: [U_IN, 0.0],
        length: DIAMETER,
    };
    let windows = run_jobs(&jobs, options.threads, |&(i, re, l)| {
        let base = &base_states[i * levels.len() + l];
        w.window(&levels[l], base, (re, viscosity(re)), &tick)
    })?;
    bar.finish_and_clear();
    let mut per_re = Vec::new();
    for (pair, level_windows) in jobs.chunks(levels.len()).zip(windows.chunks(levels.len())) {
        let (i, re, _) = pair[0];
        let (ours, finer) = (&level_windows[0], &level_windows[1]);
        let (state, deviation) = w.difference(ours, finer, re)?;
        println!(
            "  {:?} Re {re:>6}: reference against one level finer, state {state:.4}, deviation {deviation:.4}",
            splits[i].0
        );
        per_re.push(json!({
            "split": format!("{:?}", splits[i].0),
            "re": re,
            "state_difference": state,
            "deviation_difference": deviation,
            format!("forces_{}x", levels[0].factor): ours.forces_json(sizes.dt, DIAMETER, U_IN),
            format!("forces_{}x", levels[1].factor): finer.forces_json(sizes.dt, DIAMETER, U_IN),
        }));
    }
    Ok(json!({
        "data_seed": data_seed,
        "levels": levels.iter().map(|l| [l.fine.grid().ny, l.fine.grid().nx]).collect::<Vec<_>>(),
        "recorded_steps": sizes.record,
        "per_re": per_re,
    }))
}
