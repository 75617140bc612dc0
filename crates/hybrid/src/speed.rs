//! Speed against accuracy: a corrected coarse solver and uncorrected finer
//! ones rolled out from the same starts against the same reference, timed
//! per coarse step.
//!
//! Every solver is measured on the same [`Case`]s: a start (on a fine grid,
//! restricted to each solver's own), the viscosity, and the reference's
//! states on the coarse grid after each coarse step. A finer solver at
//! `level` × the coarse resolution takes `level` substeps per coarse step
//! (its own `dt` is the coarse one over `level`) and is restricted to the
//! coarse grid after each coarse step to be compared. The error is the mean
//! over the cases and steps of the velocity's relative L2 error
//! ([`crate::metrics::velocity_error`]); the time is the wall time of the
//! steps alone (restrictions and errors not counted), per coarse step and
//! sample.

use std::time::Instant;

use diffphys_flow::{restrict_velocity, FlowGrid, FlowParams, FlowState, Scene};
use diffphys_learn::{Corrector, Hybrid, State};
use diffphys_nn::Params;
use ndarray::{Array2, ArrayView2, Axis, Ix2};

use diffphys_report::chart::{line_chart_svg, LineChart, Series};
use serde_json::{json, Value};

use crate::metrics::{velocity_deviation_error, velocity_error};
use crate::reference::Reference;
use crate::{FlowSimulator, HybridError, Result};

/// One rollout of the study.
#[derive(Debug, Clone, Copy)]
pub struct Case<'a> {
    /// The kinematic viscosity.
    pub viscosity: f64,
    /// The start's velocity `(u_x, u_y)` on a grid `fine_factor` × the coarse
    /// one.
    pub fine_start: (ArrayView2<'a, f64>, ArrayView2<'a, f64>),
    /// How much finer the start's grid is than the coarse grid.
    pub fine_factor: usize,
    /// The coarse solver's start state (the reference's, on the coarse grid).
    pub coarse_start: &'a FlowState<f64>,
    /// The reference on the coarse grid after each coarse step (the rollout
    /// runs this many steps).
    pub targets: &'a [FlowState<f64>],
    /// The free stream `U` the deviation error takes out.
    pub free_stream: [f64; 2],
}

/// What one solver measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timed {
    /// The mean relative L2 error of the velocity over the cases and steps.
    pub rel_error: f64,
    /// The same for the velocity's deviation from the free stream
    /// ([`crate::metrics::velocity_deviation_error`]).
    pub deviation_error: f64,
    /// Wall seconds per coarse step and sample.
    pub seconds_per_step: f64,
}

impl Timed {
    fn of((err, deviation): (f64, f64), seconds: f64, steps: f64) -> Result<Self> {
        if steps == 0.0 {
            return Err(HybridError::Trajectory {
                what: "speed study",
                message: "no case with a step to time".into(),
            });
        }
        Ok(Timed {
            rel_error: err / steps,
            deviation_error: deviation / steps,
            seconds_per_step: seconds / steps,
        })
    }
}

/// The uncorrected `scene` at `level` × the resolution of `coarse`, rolled
/// out over `cases`.
///
/// # Errors
/// [`HybridError::Trajectory`] without a step to time; a restriction (a
/// `level` that does not divide the start's factor) or a step that fails.
pub fn finer(scene: &Scene, level: usize, coarse: &FlowGrid, cases: &[Case<'_>]) -> Result<Timed> {
    let (mut err, mut seconds, mut steps) = ((0.0, 0.0), 0.0, 0.0);
    for case in cases {
        let p = FlowParams {
            viscosity: case.viscosity,
            ..scene.params()
        };
        if level == 0 || case.fine_factor % level != 0 {
            return Err(HybridError::Trajectory {
                what: "speed study",
                message: format!(
                    "a solver at {level}x the coarse grid cannot start from a state at {}x",
                    case.fine_factor
                ),
            });
        }
        let (fx, fy) = case.fine_start;
        let (ux, uy) = restrict_velocity(scene.grid(), case.fine_factor / level, fx, fy)?;
        let mut s = FlowState::from_velocity(scene, ux, uy);
        for target in case.targets {
            let t0 = Instant::now();
            for _ in 0..level {
                s = scene.forward(&s, &p)?.0;
            }
            seconds += t0.elapsed().as_secs_f64();
            steps += 1.0;
            let (cx, cy) = restrict_velocity(coarse, level, s.ux.view(), s.uy.view())?;
            add_errors(&mut err, (&cx, &cy), target, case.free_stream);
        }
    }
    Timed::of(err, seconds, steps)
}

/// The hybrid of the coarse solver and `corrector` (`params = None`: the
/// solver alone) rolled out over `cases`, one sample at a time (the network
/// included in the time).
///
/// # Errors
/// [`HybridError::Trajectory`] without a step to time; a step that fails.
pub fn corrected<C: Corrector + 'static>(
    hybrid: &Hybrid<FlowSimulator, C>,
    params: Option<&Params<f64>>,
    cases: &[Case<'_>],
) -> Result<Timed> {
    let (mut err, mut seconds, mut steps) = ((0.0, 0.0), 0.0, 0.0);
    for case in cases {
        let mut u = State::stack(&[&hybrid.simulator().sample(case.coarse_start, case.viscosity)])?;
        for target in case.targets {
            let t0 = Instant::now();
            u = hybrid.step_plain(params, &u)?;
            seconds += t0.elapsed().as_secs_f64();
            let one = |c: usize| {
                u.fields[c]
                    .index_axis(Axis(0), 0)
                    .to_owned()
                    .into_dimensionality::<Ix2>()
            };
            let (ux, uy) = (one(0).map_err(shape)?, one(1).map_err(shape)?);
            add_errors(&mut err, (&ux, &uy), target, case.free_stream);
            steps += 1.0;
        }
    }
    Timed::of(err, seconds, steps)
}

/// Adds the state's and the deviation's error of `u` against `target`.
fn add_errors(
    sums: &mut (f64, f64),
    u: (&Array2<f64>, &Array2<f64>),
    target: &FlowState<f64>,
    free_stream: [f64; 2],
) {
    sums.0 += velocity_error(u, target);
    sums.1 += velocity_deviation_error(u, target, free_stream);
}

/// A state field that is not two-dimensional.
fn shape(e: ndarray::ShapeError) -> HybridError {
    HybridError::Trajectory {
        what: "speed study",
        message: format!("a velocity field that is not 2-D: {e}"),
    }
}

/// The cases of a study on `refs`: from each of `speed_starts` (each one of
/// the references' recorded `starts`, whose fine states they keep, on a grid
/// `factor` × the coarse one), `rollout` coarse steps; the deviation errors
/// take out `free_stream`.
///
/// # Errors
/// [`HybridError::Trajectory`] for a speed start that is not a recorded
/// start, or a reference too short for the rollout.
pub fn cases<'a>(
    refs: &'a [Reference],
    (starts, speed_starts): (&[usize], &[usize]),
    factor: usize,
    rollout: usize,
    free_stream: [f64; 2],
) -> Result<Vec<Case<'a>>> {
    let trajectory = |message: String| HybridError::Trajectory {
        what: "speed study",
        message,
    };
    let mut cases = Vec::new();
    for r in refs {
        for &start in speed_starts {
            let k = (starts.iter().position(|&s| s == start))
                .filter(|&k| k < r.fine_starts.len())
                .ok_or_else(|| {
                    trajectory(format!("speed start {start} is not a recorded start"))
                })?;
            let targets = r.states.get(start + 1..=start + rollout).ok_or_else(|| {
                trajectory(format!(
                    "a reference of {} states has no {rollout} steps from {start}",
                    r.states.len()
                ))
            })?;
            let (fx, fy) = &r.fine_starts[k];
            cases.push(Case {
                viscosity: r.viscosity,
                fine_start: (fx.view(), fy.view()),
                fine_factor: factor,
                coarse_start: &r.states[start],
                targets,
                free_stream,
            });
        }
    }
    Ok(cases)
}

/// One solver's row of a speed study.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// What the solver is (`"uncorrected 64 x 128"`).
    pub solver: String,
    /// Its resolution over the coarse one.
    pub level: usize,
    /// What it measured.
    pub timed: Timed,
}

/// A speed study's rows, in the order they were measured.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    /// The rows.
    pub rows: Vec<Row>,
}

impl Table {
    /// Adds a row and prints it.
    pub fn push(&mut self, solver: impl Into<String>, level: usize, timed: Timed) {
        let solver = solver.into();
        println!(
            "  speed: {solver:<40} error {:.4} (deviation {:.4}), {:.2} ms per step",
            timed.rel_error,
            timed.deviation_error,
            timed.seconds_per_step * 1e3
        );
        self.rows.push(Row {
            solver,
            level,
            timed,
        });
    }

    /// The row of `solver`.
    pub fn get(&self, solver: &str) -> Option<&Row> {
        self.rows.iter().find(|r| r.solver == solver)
    }

    /// The rows as JSON: `[{"solver", "level", "rel_error",
    /// "deviation_error", "ms_per_step"}]`.
    pub fn rows_json(&self) -> Value {
        self.rows
            .iter()
            .map(|r| {
                json!({"solver": r.solver, "level": r.level, "rel_error": r.timed.rel_error,
                       "deviation_error": r.timed.deviation_error,
                       "ms_per_step": r.timed.seconds_per_step * 1e3})
            })
            .collect()
    }

    /// Error against wall time per step, one point per row (log-log), at
    /// `path`; nothing is written without rows.
    ///
    /// # Errors
    /// [`HybridError::Learn`] (a report error) if the chart cannot be
    /// written.
    pub fn chart(&self, path: &std::path::Path, title: &str) -> Result<()> {
        let series: Vec<Series> = (self.rows.iter())
            .map(|r| {
                let point = (r.timed.seconds_per_step * 1e3, r.timed.rel_error);
                Series::new(r.solver.clone(), vec![point])
            })
            .collect();
        if series.is_empty() {
            return Ok(());
        }
        line_chart_svg(
            path,
            &LineChart {
                title,
                x_label: "ms per step (network included)",
                y_label: "mean relative L2 error over the rollout",
                log_x: true,
                log_y: true,
                series: &series,
            },
        )
        .map_err(|e| HybridError::Learn(e.into()))
    }
}
