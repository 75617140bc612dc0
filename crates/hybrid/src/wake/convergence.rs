//! Is the reference converged? The reference's scheme at its own
//! resolution (the channel's factor × the coarse one) against the same
//! scheme one level finer (twice that), both from the same analytic start
//! of each split, both restricted to the coarse grid: the difference, per Re
//! and per step of the recorded window, measured as the held-out errors are
//! (the relative L2 error of the state and of the velocity's deviation from
//! the free stream). Beside it, each level's forces on the body over the
//! window: the mean drag coefficient, the lift's periods (has the shedding
//! settled?) and the Strouhal number from them.

use diffphys_flow::PressureSolver;
use diffphys_learn::study::run_jobs;
use diffphys_learn::{DataSeed, Split};
use diffphys_report::progress_bar;
use serde_json::{json, Value};

use super::{Bump, Wake};
use crate::convergence::{Level, Windows};
use crate::reference::advance;
use crate::Result;

impl Wake {
    /// The convergence check at the train, validation and held-out Re of
    /// `re` (data seed `data_seed`'s draws), on `threads` workers.
    ///
    /// # Errors
    /// Whatever the scenes and the solvers return.
    pub fn convergence(&self, re: [&[f64]; 3], data_seed: u64, threads: usize) -> Result<Value> {
        let (c, s) = (&self.channel, &self.sizes);
        let coarse = self.uncorrected(1, PressureSolver::Cholesky)?;
        let levels = [c.factor, 2 * c.factor]
            .map(|factor| {
                let fine = self.reference_scene_at(factor)?;
                Ok(Level { factor, fine })
            })
            .into_iter()
            .collect::<Result<Vec<_>>>()?;
        let splits = [Split::Train, Split::Validation, Split::HeldOut];
        let runs: usize = re.iter().map(|r| r.len()).sum();
        let bar = progress_bar(
            levels.len() * (splits.len() * s.warm_base + runs * (s.warm + s.record)),
            "reference convergence",
        );
        let tick = |n| bar.inc(n);
        // Each split's base state at each level, from the split's own draw.
        let bases: Vec<(usize, Bump)> = splits
            .iter()
            .flat_map(|&split| {
                let bump = self.draw_bump(&mut DataSeed(data_seed).rng(split));
                (0..levels.len()).map(move |l| (l, bump))
            })
            .collect();
        let base_states = run_jobs(&bases, threads, |&(l, bump)| {
            let fine = &levels[l].fine;
            let start = self.start_state(fine, bump);
            let nu = c.viscosity(s.base_re);
            advance(fine, levels[l].factor, start, nu, s.warm_base, &tick)
        })?;
        let n = levels.len();
        let jobs: Vec<(usize, f64, usize)> = (re.iter().enumerate())
            .flat_map(|(i, res)| {
                res.iter()
                    .flat_map(move |&re| (0..n).map(move |l| (i, re, l)))
            })
            .collect();
        let w = Windows {
            coarse: &coarse,
            warm: s.warm,
            record: s.record,
            free_stream: [c.inflow, 0.0],
            length: c.diameter,
        };
        // the finer level keeps its fine velocity at the rollout starts
        let kept = |l: usize| if l + 1 == n { &s.starts[..] } else { &[][..] };
        let windows = run_jobs(&jobs, threads, |&(i, re, l)| {
            let base = &base_states[i * n + l];
            w.window(&levels[l], base, (re, c.viscosity(re)), kept(l), &tick)
        })?;
        bar.finish_and_clear();
        // the reference restarted from the finer level over each rollout
        let ratio = levels[1].factor / levels[0].factor;
        let per_pair: Vec<usize> = (0..jobs.len() / n).collect();
        let horizons = run_jobs(&per_pair, threads, |&k| {
            let re = jobs[k * n].1;
            let finer = &windows[k * n + 1];
            let setting = (&s.starts[..], s.rollout, ratio);
            w.horizon((&levels[0], finer), setting, (re, c.viscosity(re)), &|_| {})
        })?;
        let mut per_re = Vec::new();
        let pairs = jobs.chunks(n).zip(windows.chunks(n)).zip(&horizons);
        for ((pair, level_windows), &(h_state, h_deviation)) in pairs {
            let (i, re, _) = pair[0];
            let (ours, finer) = (&level_windows[0], &level_windows[1]);
            let (state, deviation) = w.difference(ours, finer, re)?;
            println!(
                "  {:?} Re {re:>6}: reference against one level finer, state {state:.4}, deviation {deviation:.4}; over a rollout from the finer state {h_state:.4}, {h_deviation:.4}",
                splits[i]
            );
            let forces =
                |win: &crate::convergence::Window| win.forces_json(s.dt, c.diameter, c.inflow);
            per_re.push(json!({
                "split": format!("{:?}", splits[i]),
                "re": re,
                "state_difference": state,
                "deviation_difference": deviation,
                "rollout_state_difference": h_state,
                "rollout_deviation_difference": h_deviation,
                format!("forces_{}x", levels[0].factor): forces(ours),
                format!("forces_{}x", levels[1].factor): forces(finer),
            }));
        }
        Ok(json!({
            "data_seed": data_seed,
            "levels": levels.iter().map(|l| [l.fine.grid().ny, l.fine.grid().nx]).collect::<Vec<_>>(),
            "recorded_steps": s.record,
            "rollout_starts": s.starts,
            "rollout_steps": s.rollout,
            "per_re": per_re,
        }))
    }
}
