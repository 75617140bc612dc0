//! Is a reference converged? The reference's scheme at its own resolution
//! against the same scheme one level finer, both from the same start, both
//! restricted to the coarse grid: the difference per step of the recorded
//! window, measured as a hybrid's held-out errors are (the state's relative
//! L2 error and the velocity's deviation from the free stream), and each
//! level's forces on the body over the window (the mean drag coefficient,
//! the lift's periods and the Strouhal number from them).
//!
//! Two levels run apart from a common start drift out of phase where the
//! wake sheds; a hybrid, though, is trained and scored on rollouts that start
//! from the reference's own states. So the check also measures the
//! difference over that horizon ([`Windows::horizon`]): the coarser level
//! restarted from the finer level's state at each rollout start, against
//! the finer level over the rollout.

use diffphys_flow::diagnostics::obstacle_force;
use diffphys_flow::restrict::restrict_velocity;
use diffphys_flow::validation::Shedding;
use diffphys_flow::{FlowState, Scene};
use ndarray::Array2;
use serde_json::{json, Value};

use crate::metrics::{velocity_deviation_error, velocity_error};
use crate::reference::{advance, Recorder};
use crate::{HybridError, Result};

/// One level of the check: a fine scene at `factor` × the coarse grid.
pub struct Level {
    /// How much finer than the coarse grid it is.
    pub factor: usize,
    /// The fine scene.
    pub fine: Scene,
}

/// One level's recorded window at one Reynolds number: the states
/// restricted to the coarse grid and the force coefficients `2 F / (U² D)`
/// `(c_D, c_L)` at each.
#[derive(Debug, Clone)]
pub struct Window {
    /// The states on the coarse grid.
    pub states: Vec<FlowState<f64>>,
    /// `(c_D, c_L)` after each coarse step.
    pub forces: Vec<[f64; 2]>,
    /// The fine velocity at each of the rollout starts asked for.
    pub fine_starts: Vec<(ndarray::Array2<f64>, ndarray::Array2<f64>)>,
}

/// What every window of a check shares.
pub struct Windows<'a> {
    /// The coarse scene the windows are restricted to.
    pub coarse: &'a Scene,
    /// Coarse steps skipped before the window.
    pub warm: usize,
    /// Coarse steps recorded.
    pub record: usize,
    /// The free stream `(U, 0)`.
    pub free_stream: [f64; 2],
    /// The body's length (the cylinder's diameter) of the coefficients.
    pub length: f64,
}

impl Windows<'_> {
    /// `record` coarse steps of `level` at `(re, nu)` after `warm` from
    /// `base`, keeping the fine velocity at the recorded steps `starts`;
    /// `tick` counts the coarse steps.
    ///
    /// # Errors
    /// Whatever the recording and the force evaluation return.
    pub fn window(
        &self,
        level: &Level,
        base: &FlowState<f64>,
        (re, nu): (f64, f64),
        starts: &[usize],
        tick: &(dyn Fn(u64) + Sync),
    ) -> Result<Window> {
        let u = self.free_stream[0];
        let scale = 2.0 / (u * u * self.length);
        let mut forces = Vec::new();
        let recorder = Recorder {
            fine: &level.fine,
            coarse: self.coarse,
            factor: level.factor,
            warm: self.warm,
            record: self.record,
            starts,
        };
        let reference = recorder.record(base, (re, nu), tick, &mut |s| {
            let w = level.fine.force_weights();
            let f = obstacle_force(w, s.ux.view(), s.uy.view(), s.pressure.view(), nu)?;
            forces.push([scale * f[0], scale * f[1]]);
            Ok(())
        })?;
        Ok(Window {
            states: reference.states,
            forces,
            fine_starts: reference.fine_starts,
        })
    }

    /// The difference over a rollout's horizon at `(re, nu)`: from the finer
    /// level's fine velocity at each start it kept (its window's
    /// `fine_starts`, at the recorded steps `starts`), restricted to `ours`'
    /// grid, `ours` runs `rollout` coarse steps (a zero-pressure start, as a
    /// rollout's); each step is compared, on the coarse grid, with the finer
    /// window's state. Mean over starts and steps: `(state, deviation)`.
    ///
    /// # Errors
    /// [`HybridError::Trajectory`] if the finer window kept other starts, a
    /// start's rollout leaves the window, or the difference is not finite;
    /// a step's or a restriction's error.
    pub fn horizon(
        &self,
        (ours, finer): (&Level, &Window),
        (starts, rollout, ratio): (&[usize], usize, usize),
        (re, nu): (f64, f64),
        tick: &(dyn Fn(u64) + Sync),
    ) -> Result<(f64, f64)> {
        let bad = |message: String| HybridError::Trajectory {
            what: "reference convergence over a rollout",
            message,
        };
        if finer.fine_starts.len() != starts.len() || rollout == 0 {
            return Err(bad(format!(
                "{} kept starts for {} asked, a rollout of {rollout} steps",
                finer.fine_starts.len(),
                starts.len()
            )));
        }
        let (mut state, mut deviation, mut n) = (0.0, 0.0, 0.0);
        for (&t0, (fx, fy)) in starts.iter().zip(&finer.fine_starts) {
            if t0 + rollout >= finer.states.len() {
                return Err(bad(format!(
                    "a rollout of {rollout} steps from step {t0} leaves the window of {}",
                    finer.states.len()
                )));
            }
            let grid = ours.fine.grid();
            let (ux, uy) = restrict_velocity(grid, ratio, fx.view(), fy.view())?;
            let mut s = FlowState::from_velocity(&ours.fine, ux, uy);
            for k in 1..=rollout {
                s = advance(&ours.fine, ours.factor, s, nu, 1, tick)?;
                let (cx, cy) =
                    restrict_velocity(self.coarse.grid(), ours.factor, s.ux.view(), s.uy.view())?;
                let (e, d) = self.step_difference((&cx, &cy), &finer.states[t0 + k]);
                (state, deviation, n) = (state + e, deviation + d, n + 1.0);
            }
        }
        let (state, deviation) = (state / n, deviation / n);
        if !(state.is_finite() && deviation.is_finite()) {
            return Err(bad(format!("a non-finite difference at Re {re}")));
        }
        Ok((state, deviation))
    }

    /// One step's difference of the velocity `u` on the coarse grid from
    /// the finer level's `truth`: `(state, deviation)`.
    fn step_difference(
        &self,
        u: (&Array2<f64>, &Array2<f64>),
        truth: &FlowState<f64>,
    ) -> (f64, f64) {
        (
            velocity_error(u, truth),
            velocity_deviation_error(u, truth, self.free_stream),
        )
    }

    /// The difference of two levels' windows at one Reynolds number `re`,
    /// mean over the recorded steps: `(state, deviation)`.
    ///
    /// # Errors
    /// [`HybridError::Trajectory`] for windows of other lengths or a
    /// non-finite difference.
    pub fn difference(&self, ours: &Window, finer: &Window, re: f64) -> Result<(f64, f64)> {
        let bad = |message: String| HybridError::Trajectory {
            what: "reference convergence",
            message,
        };
        if ours.states.len() != finer.states.len() || ours.states.len() < 2 {
            return Err(bad(format!(
                "windows of {} and {} states at Re {re}",
                ours.states.len(),
                finer.states.len()
            )));
        }
        let steps = 1..ours.states.len();
        let n = steps.len() as f64;
        let (mut state, mut deviation) = (0.0, 0.0);
        for t in steps {
            let s = &ours.states[t];
            let (e, d) = self.step_difference((&s.ux, &s.uy), &finer.states[t]);
            (state, deviation) = (state + e, deviation + d);
        }
        let (state, deviation) = (state / n, deviation / n);
        if !(state.is_finite() && deviation.is_finite()) {
            return Err(bad(format!(
                "the reference at Re {re} and one level finer differ by a non-finite amount"
            )));
        }
        Ok((state, deviation))
    }
}

impl Window {
    /// The forces over the window: mean drag, lift amplitude, the lift's
    /// periods, whether they agree to 1 %, and the Strouhal number
    /// `D / (U T̄)` (null with fewer than two up-crossings); `dt` is the
    /// coarse step.
    pub fn forces_json(&self, dt: f64, length: f64, speed: f64) -> Value {
        let n = self.forces.len().max(1) as f64;
        let lift: Vec<f64> = self.forces.iter().map(|f| f[1]).collect();
        let amplitude = 0.5
            * (lift.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                - lift.iter().copied().fold(f64::INFINITY, f64::min));
        let times: Vec<f64> = (0..self.forces.len()).map(|k| k as f64 * dt).collect();
        let shedding = Shedding::of(&times, &lift);
        json!({
            "mean_cd": self.forces.iter().map(|f| f[0]).sum::<f64>() / n,
            "cl_amplitude": amplitude,
            "lift_periods": shedding.periods,
            "settled_to_1_percent": shedding.settled(0.01),
            "strouhal": shedding.strouhal(length, speed),
        })
    }
}
