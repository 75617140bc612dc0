//! Rollout metrics: the relative L2 error per step of an `n`-step rollout and its
//! mean over the steps.

use diffphys_nn::Params;
use diffphys_tape::ArrayD;
use ndarray::ArrayViewD;
use ndarray::Axis;

use crate::hybrid::{physical_fields, Corrector, Hybrid, Simulator};
use crate::state::State;
use crate::{LearnError, Result};

/// A reference trajectory of one sample: its states at steps `0, 1, …`, each a
/// sample (no batch axis).
pub type Trajectory = Vec<State>;

/// Stacks same-shaped samples into a batch along a new axis 0.
///
/// # Errors
/// [`LearnError::Invalid`] without samples or for samples of different shapes.
pub fn batch_of(samples: &[&ArrayD<f64>]) -> Result<ArrayD<f64>> {
    let views: Vec<_> = samples.iter().map(|s| s.view()).collect();
    if views.is_empty() {
        return Err(LearnError::invalid("batch", "no samples"));
    }
    ndarray::stack(Axis(0), &views).map_err(|e| LearnError::invalid("batch", e.to_string()))
}

/// States at step `t` of every trajectory, as a batch.
///
/// # Errors
/// As [`State::stack`], and [`LearnError::Invalid`] if a trajectory is shorter.
pub fn states_at(trajectories: &[Trajectory], t: usize) -> Result<State> {
    let rows = trajectories
        .iter()
        .map(|tr| {
            tr.get(t).ok_or_else(|| {
                LearnError::invalid(
                    "trajectory",
                    format!("step {t} asked of a trajectory of {} states", tr.len()),
                )
            })
        })
        .collect::<Result<Vec<_>>>()?;
    State::stack(&rows)
}

/// The mean over the batch (axis 0) of `‖a_b − r_b‖ / ‖r_b‖`.
pub fn relative_l2(a: &ArrayD<f64>, r: &ArrayD<f64>) -> f64 {
    relative_l2_fields(std::slice::from_ref(a), std::slice::from_ref(r))
}

/// [`relative_l2`] over several fields of a batch taken together: the mean
/// over the batch of `‖a_b − r_b‖ / ‖r_b‖`, the norms over every entry of
/// every field of sample `b`.
pub fn relative_l2_fields(a: &[ArrayD<f64>], r: &[ArrayD<f64>]) -> f64 {
    let batch = r
        .first()
        .map_or(0, |f| f.shape().first().copied().unwrap_or(0));
    let per_sample: Vec<f64> = (0..batch)
        .map(|b| {
            let (mut diff, mut norm) = (0.0, 0.0);
            for (x, y) in a.iter().zip(r) {
                let (x, y) = (x.index_axis(Axis(0), b), y.index_axis(Axis(0), b));
                diff += x
                    .iter()
                    .zip(y.iter())
                    .map(|(p, q)| (p - q).powi(2))
                    .sum::<f64>();
                norm += y.iter().map(|q| q * q).sum::<f64>();
            }
            (diff / norm).sqrt()
        })
        .collect();
    per_sample.iter().sum::<f64>() / per_sample.len().max(1) as f64
}

/// An error of one predicted sample against its reference sample, each given
/// as its fields (without the batch axis), for [`rollout_measured`]: a scene's
/// own measure beside the relative L2 error of the physical fields (the error
/// of the velocity's deviation from the free stream, of the vorticity, …).
pub type Metric<'a> = &'a (dyn Fn(&[ArrayViewD<'_, f64>], &[ArrayViewD<'_, f64>]) -> f64 + Sync);

/// The errors of one rollout against the reference.
#[derive(Debug, Clone)]
pub struct Rollout {
    /// The relative L2 error of the physical fields after steps `1..=n`, mean
    /// over the trajectories.
    pub per_step: Vec<f64>,
    /// Per metric given to [`rollout_measured`], in order: its error after
    /// steps `1..=n`, mean over the trajectories (empty for [`rollout`]).
    pub measured: Vec<Vec<f64>>,
    /// The states after the last step, as a batch.
    pub last: State,
}

impl Rollout {
    /// The mean of the per-step errors: the rollout's score.
    pub fn mean(&self) -> f64 {
        mean(&self.per_step)
    }

    /// The mean over the steps of metric `i` of [`rollout_measured`].
    pub fn measured_mean(&self, i: usize) -> Option<f64> {
        self.measured.get(i).map(|m| mean(m))
    }
}

/// The fields of sample `b` of the batch `s`, as views.
fn sample(s: &State, b: usize) -> Vec<ArrayViewD<'_, f64>> {
    s.fields.iter().map(|f| f.index_axis(Axis(0), b)).collect()
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Rolls the hybrid out for `steps` steps from the first state of every
/// trajectory (`params = None`: the solver alone) and measures the relative L2
/// error against the trajectories at every step.
///
/// # Errors
/// [`LearnError::EmptySplit`]-like [`LearnError::Invalid`] without trajectories
/// or with trajectories shorter than `steps + 1`; [`LearnError::ZeroUnroll`] for
/// 0 steps; whatever the steps return.
pub fn rollout<S: Simulator + 'static, C: Corrector + 'static>(
    hybrid: &Hybrid<S, C>,
    params: Option<&Params<f64>>,
    trajectories: &[Trajectory],
    steps: usize,
) -> Result<Rollout> {
    rollout_measured(hybrid, params, trajectories, steps, &[])
}

/// [`rollout`] from each trajectory on its own: one mean relative L2 error
/// per trajectory (per condition, when each trajectory holds one: a Reynolds
/// number, a forcing).
///
/// # Errors
/// As [`rollout`].
pub fn rollout_each<S: Simulator + 'static, C: Corrector + 'static>(
    hybrid: &Hybrid<S, C>,
    params: Option<&Params<f64>>,
    trajectories: &[Trajectory],
    steps: usize,
) -> Result<Vec<f64>> {
    trajectories
        .iter()
        .map(|t| Ok(rollout(hybrid, params, std::slice::from_ref(t), steps)?.mean()))
        .collect()
}

/// [`rollout`], measuring every metric of `metrics` too at every step: each
/// the mean over the trajectories of `metric(predicted, reference)`.
///
/// # Errors
/// As [`rollout`]; [`LearnError::Invalid`] when a metric comes out NaN
/// (a reference on which it is not defined, such as a zero norm).
pub fn rollout_measured<S: Simulator + 'static, C: Corrector + 'static>(
    hybrid: &Hybrid<S, C>,
    params: Option<&Params<f64>>,
    trajectories: &[Trajectory],
    steps: usize,
    metrics: &[Metric<'_>],
) -> Result<Rollout> {
    if steps == 0 {
        return Err(LearnError::ZeroUnroll { what: "rollout" });
    }
    if trajectories.is_empty() {
        return Err(LearnError::invalid("rollout", "no trajectories"));
    }
    let mut u = states_at(trajectories, 0)?;
    let physical = physical_fields(hybrid.simulator(), u.fields.len());
    let mut per_step = Vec::with_capacity(steps);
    let mut measured = vec![Vec::with_capacity(steps); metrics.len()];
    for t in 1..=steps {
        u = hybrid.step_plain(params, &u)?;
        let reference = states_at(trajectories, t)?;
        per_step.push(relative_l2_fields(
            &u.fields[..physical],
            &reference.fields[..physical],
        ));
        for (metric, errors) in metrics.iter().zip(&mut measured) {
            let error = mean(
                &(0..u.batch_len())
                    .map(|b| metric(&sample(&u, b), &sample(&reference, b)))
                    .collect::<Vec<_>>(),
            );
            if error.is_nan() {
                return Err(LearnError::invalid(
                    "rollout metric",
                    format!("metric {} is NaN after step {t}", errors.len()),
                ));
            }
            errors.push(error);
        }
    }
    Ok(Rollout {
        per_step,
        measured,
        last: u,
    })
}

/// Whether a validation `score` should replace the `best` so far (none yet:
/// always): a lower score does, and a NaN score is worse than any other, so a
/// NaN first score is replaced by the first real one and never replaces one.
pub(crate) fn improves(score: f64, best: Option<f64>) -> bool {
    match best {
        None => true,
        Some(b) => !score.is_nan() && (b.is_nan() || score < b),
    }
}

#[cfg(test)]
mod tests {
    use super::improves;

    #[test]
    fn nan_scores_never_win_and_are_always_replaced() {
        assert!(improves(0.5, None));
        assert!(improves(f64::NAN, None));
        assert!(improves(0.4, Some(0.5)));
        assert!(!improves(0.5, Some(0.5)));
        assert!(!improves(0.6, Some(0.5)));
        assert!(improves(0.6, Some(f64::NAN)));
        assert!(!improves(f64::NAN, Some(0.5)));
        assert!(!improves(f64::NAN, Some(f64::NAN)));
        assert!(improves(1e300, Some(f64::INFINITY)));
    }
}
