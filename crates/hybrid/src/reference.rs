//! Reference trajectories: a finer solver's states restricted to the coarse
//! grid, the data a corrector learns from and is scored against; and the
//! rollouts of a hybrid scored against one.
//!
//! A [`Recorder`] advances a fine scene (`factor` fine steps per coarse step)
//! from a start: `warm` coarse steps it skips (the transient), then `record`
//! coarse steps, each restricted to the coarse grid (the velocity by face
//! averages, the pressure by cell averages: [`diffphys_flow::restrict`]),
//! and the fine velocity at the chosen starts (finer solvers start from it,
//! [`crate::speed`]). [`Reference::to_arrays`] and [`Reference::from_arrays`]
//! are its cache form ([`diffphys_learn::cache`]). [`evaluate`] rolls a hybrid
//! out on a reference from several starts and once over a long horizon.

use diffphys_flow::{restrict_pressure, restrict_velocity, FlowParams, FlowState, Scene};
use diffphys_learn::cache::Arrays;
use diffphys_learn::{rollout, rollout_measured, Corrector, Hybrid, Trajectory};
use diffphys_nn::Params;
use ndarray::{Array, Array2, ArrayD, Axis, Dimension, Ix2, Ix3};

use crate::metrics::{deviation_error, vorticity_error, Fields};
use crate::{sample, FlowSimulator, HybridError, Result};

/// A reference trajectory at one viscosity, on the coarse grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// The Reynolds number the scene gives this viscosity (a label: the
    /// solvers read [`Reference::viscosity`]).
    pub re: f64,
    /// The kinematic viscosity.
    pub viscosity: f64,
    /// `record + 1` coarse states (velocity and pressure, restricted).
    pub states: Vec<FlowState<f64>>,
    /// The fine velocity `(u_x, u_y)` at each of the recorder's starts.
    pub fine_starts: Vec<(Array2<f64>, Array2<f64>)>,
}

/// `coarse_steps` coarse steps of `fine` at `viscosity`, `factor` fine steps
/// each; `tick(1)` after each coarse step.
///
/// # Errors
/// A step that fails.
pub fn advance(
    fine: &Scene,
    factor: usize,
    mut s: FlowState<f64>,
    viscosity: f64,
    coarse_steps: usize,
    tick: &(dyn Fn(u64) + Sync),
) -> Result<FlowState<f64>> {
    let p = FlowParams {
        viscosity,
        ..fine.params()
    };
    for _ in 0..coarse_steps {
        for _ in 0..factor {
            s = fine.forward(&s, &p)?.0;
        }
        tick(1);
    }
    Ok(s)
}

/// How a reference is recorded.
#[derive(Debug, Clone, Copy)]
pub struct Recorder<'a> {
    /// The solver that makes it.
    pub fine: &'a Scene,
    /// The grid it is restricted to (and whose states it holds).
    pub coarse: &'a Scene,
    /// How much finer `fine` is than `coarse`, in space and time.
    pub factor: usize,
    /// Coarse steps skipped before recording.
    pub warm: usize,
    /// Coarse steps recorded.
    pub record: usize,
    /// The recorded steps whose fine velocity is kept.
    pub starts: &'a [usize],
}

impl Recorder<'_> {
    /// The reference from the fine state `base` at `viscosity` (labelled
    /// `re`); `observe` sees every recorded fine state (the forces on a body,
    /// say), `tick(1)` follows every coarse step.
    ///
    /// # Errors
    /// A step or a restriction that fails; whatever `observe` returns.
    pub fn record(
        &self,
        base: &FlowState<f64>,
        (re, viscosity): (f64, f64),
        tick: &(dyn Fn(u64) + Sync),
        observe: &mut dyn FnMut(&FlowState<f64>) -> Result<()>,
    ) -> Result<Reference> {
        let (fine, coarse, factor) = (self.fine, self.coarse, self.factor);
        let mut s = advance(fine, factor, base.clone(), viscosity, self.warm, tick)?;
        let p = FlowParams {
            viscosity,
            ..fine.params()
        };
        let (mut states, mut fine_starts) = (Vec::new(), Vec::new());
        for t in 0..=self.record {
            if t > 0 {
                for _ in 0..factor {
                    s = fine.forward(&s, &p)?.0;
                }
                tick(1);
            }
            let (ux, uy) = restrict_velocity(coarse.grid(), factor, s.ux.view(), s.uy.view())?;
            let pressure = restrict_pressure(coarse.grid(), factor, s.pressure.view())?;
            states.push(FlowState {
                pressure,
                ..FlowState::from_velocity(coarse, ux, uy)
            });
            if self.starts.contains(&t) {
                fine_starts.push((s.ux.clone(), s.uy.clone()));
            }
            observe(&s)?;
        }
        Ok(Reference {
            re,
            viscosity,
            states,
            fine_starts,
        })
    }
}

/// The array called `name` of `arrays`, with `D` dimensions.
fn take<D: Dimension>(arrays: &mut Arrays, name: &str) -> Result<Array<f64, D>> {
    let bad = |message: String| HybridError::Trajectory {
        what: "reference arrays",
        message: format!("{name}: {message}"),
    };
    let at = arrays.iter().position(|(n, _)| n == name);
    let (_, a) = at
        .map(|i| arrays.swap_remove(i))
        .ok_or_else(|| bad("missing".into()))?;
    a.into_dimensionality().map_err(|e| bad(e.to_string()))
}

/// `arrays`, each with a new leading axis, stacked.
fn stacked<'a, D: Dimension + 'a>(
    arrays: impl Iterator<Item = &'a Array<f64, D>>,
) -> Result<ArrayD<f64>> {
    let views: Vec<_> = arrays.map(|a| a.view().into_dyn()).collect();
    ndarray::stack(Axis(0), &views).map_err(|e| HybridError::Trajectory {
        what: "reference arrays",
        message: e.to_string(),
    })
}

/// A flow state's velocity and pressure as named arrays (`ux`, `uy`,
/// `pressure`).
pub fn state_to_arrays(s: &FlowState<f64>) -> Arrays {
    vec![
        ("ux".into(), s.ux.clone().into_dyn()),
        ("uy".into(), s.uy.clone().into_dyn()),
        ("pressure".into(), s.pressure.clone().into_dyn()),
    ]
}

/// The state [`state_to_arrays`] wrote (no scalars).
///
/// # Errors
/// [`HybridError::Trajectory`] for a missing array or one of another rank.
pub fn state_from_arrays(mut arrays: Arrays) -> Result<FlowState<f64>> {
    Ok(FlowState {
        ux: take::<Ix2>(&mut arrays, "ux")?,
        uy: take::<Ix2>(&mut arrays, "uy")?,
        pressure: take::<Ix2>(&mut arrays, "pressure")?,
        scalars: Vec::new(),
    })
}

impl Reference {
    /// The reference as named arrays, each over the steps (`ux`, `uy`,
    /// `pressure`, `fine_ux`, `fine_uy`).
    ///
    /// # Errors
    /// [`HybridError::Trajectory`] for states of different shapes.
    pub fn to_arrays(&self) -> Result<Arrays> {
        let s = &self.states;
        let f = &self.fine_starts;
        Ok(vec![
            ("ux".into(), stacked(s.iter().map(|s| &s.ux))?),
            ("uy".into(), stacked(s.iter().map(|s| &s.uy))?),
            ("pressure".into(), stacked(s.iter().map(|s| &s.pressure))?),
            ("fine_ux".into(), stacked(f.iter().map(|f| &f.0))?),
            ("fine_uy".into(), stacked(f.iter().map(|f| &f.1))?),
        ])
    }

    /// The reference [`Reference::to_arrays`] wrote, its states on `coarse`.
    ///
    /// # Errors
    /// [`HybridError::Trajectory`] for a missing array or one of another rank.
    pub fn from_arrays(
        mut arrays: Arrays,
        coarse: &Scene,
        (re, viscosity): (f64, f64),
    ) -> Result<Self> {
        let ux = take::<Ix3>(&mut arrays, "ux")?;
        let uy = take::<Ix3>(&mut arrays, "uy")?;
        let pressure = take::<Ix3>(&mut arrays, "pressure")?;
        let fine_ux = take::<Ix3>(&mut arrays, "fine_ux")?;
        let fine_uy = take::<Ix3>(&mut arrays, "fine_uy")?;
        Ok(Reference {
            re,
            viscosity,
            states: ux
                .outer_iter()
                .zip(uy.outer_iter())
                .zip(pressure.outer_iter())
                .map(|((ux, uy), p)| FlowState {
                    pressure: p.to_owned(),
                    ..FlowState::from_velocity(coarse, ux.to_owned(), uy.to_owned())
                })
                .collect(),
            fine_starts: fine_ux
                .outer_iter()
                .zip(fine_uy.outer_iter())
                .map(|(a, b)| (a.to_owned(), b.to_owned()))
                .collect(),
        })
    }

    /// `count` states from step `start`, as a trajectory of a
    /// [`FlowSimulator`] on `scene` ([`sample`]: the fields `scene` carries,
    /// the viscosity as each sample's parameter).
    ///
    /// # Errors
    /// [`HybridError::Trajectory`] if the reference holds fewer.
    pub fn window(&self, scene: &Scene, start: usize, count: usize) -> Result<Trajectory> {
        if start + count > self.states.len() {
            return Err(HybridError::Trajectory {
                what: "reference window",
                message: format!(
                    "a window of {count} states from step {start} needs more than the {} recorded",
                    self.states.len()
                ),
            });
        }
        Ok(self.states[start..start + count]
            .iter()
            .map(|s| sample(scene, s, self.viscosity))
            .collect())
    }
}

/// How a hybrid is scored on a reference ([`evaluate`]).
#[derive(Debug, Clone, Copy)]
pub struct Evaluation<'a> {
    /// The steps the short rollouts start from.
    pub starts: &'a [usize],
    /// The short rollouts' steps.
    pub rollout: usize,
    /// The long rollout's steps (from step 0).
    pub long: usize,
    /// The free stream the deviation is measured from
    /// ([`crate::metrics::deviation_error`]).
    pub free_stream: [f64; 2],
}

/// A hybrid's rollouts on one reference.
#[derive(Debug, Clone)]
pub struct Rollouts {
    /// The reference's Reynolds number.
    pub re: f64,
    /// The state's relative L2 error, mean over the short rollouts' steps
    /// and starts.
    pub mean: f64,
    /// The same for the velocity's deviation from the free stream.
    pub deviation: f64,
    /// The same for the vorticity.
    pub vorticity: f64,
    /// The state's error after each step, mean over the starts.
    pub curve: Vec<f64>,
    /// The state's relative L2 error, mean over the long rollout.
    pub long: f64,
    /// The long rollout's last state.
    pub last: FlowState<f64>,
}

/// The rollouts of `hybrid` (`params = None`: the solver alone) on `r`:
/// `e.rollout` steps from each of `e.starts` (the state's error, the
/// deviation's and the vorticity's), and `e.long` steps from step 0.
///
/// # Errors
/// A window the reference cannot give; whatever the rollouts return.
pub fn evaluate<C: Corrector + 'static>(
    hybrid: &Hybrid<FlowSimulator, C>,
    params: Option<&Params<f64>>,
    r: &Reference,
    e: &Evaluation<'_>,
) -> Result<Rollouts> {
    let scene = hybrid.simulator().scene();
    let windows = e
        .starts
        .iter()
        .map(|&s| r.window(scene, s, e.rollout + 1))
        .collect::<Result<Vec<_>>>()?;
    let deviation =
        |p: Fields<'_, '_>, q: Fields<'_, '_>| deviation_error(scene, e.free_stream, p, q);
    let vorticity = |p: Fields<'_, '_>, q: Fields<'_, '_>| vorticity_error(scene, p, q);
    let short = rollout_measured(
        hybrid,
        params,
        &windows,
        e.rollout,
        &[&deviation, &vorticity],
    )?;
    let long = rollout(hybrid, params, &[r.window(scene, 0, e.long + 1)?], e.long)?;
    let last = long.last.sample(0)?;
    let views: Vec<_> = last.fields.iter().map(|f| f.view()).collect();
    Ok(Rollouts {
        re: r.re,
        mean: short.mean(),
        deviation: short.measured_mean(0).unwrap_or(f64::NAN),
        vorticity: short.measured_mean(1).unwrap_or(f64::NAN),
        curve: short.per_step,
        long: long.mean(),
        last: scene.state_of(&views)?,
    })
}
