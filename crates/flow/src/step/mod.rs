//! The scene description and the step that composes the physics.
//!
//! A [`Scene`] is built once ([`Scene::builder`]): domain, resolution, sides,
//! obstacle, viscosity, time step, advection scheme, viscosity mode, pressure
//! solver. It assembles the stencils and factorises the pressure operator
//! then. The step is then
//!
//! ```text
//! u ← enforce_boundaries(u, inflow)             fixed faces from the sides and the obstacle
//! s ← advect_scalar(s; u)                        each passive scalar
//! u ← u − (dt/2) G P                             incremental splitting only
//! u ← advect_velocity(u; traced by uⁿ)           semi-Lagrangian or MacCormack
//! u ← u + dt β s̄ ŷ                               buoyancy, if any
//! u ← diffuse(u; ν)                               explicit or implicit
//! u ← immersed_forcing(u; c, r)                  an immersed circle, if any
//!     (or consistent_forcing(u, P; c, r))        its projection-consistent scheme
//! (u, P) ← project(u; guess P)                   τ = dt (plain) or dt/2 (incremental)
//! ```
//!
//! (with [`crate::ForcingScheme::MultiDirect`] the last two lines are one op,
//! [`crate::immersed::multi_direct_forcing`], which alternates them `K` times)
//!
//! written once in `substep` over an [`Exec`]utor: on a tape every piece is
//! recorded as an op ([`Scene::step`]); without one the same ops' forwards run
//! directly and no tape memory is allocated ([`Scene::forward`]). On a scene
//! without a fixed face (a periodic box without obstacle) the first line is
//! the identity and is not run (nothing recorded for it).
//!
//! **Splitting.** [`Splitting::Plain`] is Chorin's projection: advect, diffuse,
//! project (`P = p/dt`); first order in time. [`Splitting::Incremental`] (the
//! default) advects `u − (dt/2)∇Pⁿ` and projects with `τ = dt/2`, so that
//! along a trajectory the pressure acts at the mid-point,
//! `uⁿ⁺¹ = uⁿ(X) − (dt/2)(∇Pⁿ(X) + ∇Pⁿ⁺¹)`: the splitting error of the plain
//! scheme (first order even with MacCormack) drops to second order. The
//! pressure of the state then matters to the next step and is differentiated
//! through; its use as the warm start of the pressure solve is not.
//!
//! **CFL.** The Courant number `max |u| dt/h` of the state (and, explicit,
//! the diffusion number `ν dt (1/dx² + 1/dy²)`) are checked before the step:
//! above [`Settings::max_courant`] (or ½) the step is [`FlowError::Cfl`] unless
//! [`Settings::substepping`] is on; then it takes `n` equal substeps, the least
//! that satisfy both, and reports `n` in [`StepInfo::substeps`].

use std::rc::Rc;
use std::sync::Arc;

use diffphys_tape::pool::BufferPool;
use diffphys_tape::{
    checkpointed_steps, parallel, ArrayD, Real, Schedule, StepFn, Tape, TapeError, Var,
};
use ndarray::{Array1, Array2, ArrayView2, Ix2, IxDyn};

use crate::boundaries::Faces;
use crate::diagnostics::ForceWeights;
use crate::diffusion::{explicit_diffusion_number, Diffusion, ViscosityMode};
use crate::forcing::{Buoyancy, Forcing};
use crate::grid::FlowGrid;
use crate::immersed::{ForcingImpulse, ForcingScheme, ImmersedCircle};
use crate::pressure::{PressureSystem, SolveCounter};
use crate::sides::Side;
use crate::{FlowError, Result};

mod builder;
mod compose;
mod state;

pub use builder::{SceneBuilder, Settings, Splitting};
pub use compose::Exec;
use compose::{substep, OnTape, ParamsOf, Plain, StateOf};
pub use state::{FlowParams, FlowState, FlowVars, ParamVars, StepInfo, StepLog};

#[derive(Debug)]
pub(super) struct SceneInner {
    pub(super) grid: FlowGrid,
    pub(super) solid: Array2<bool>,
    /// Which faces are fixed; with none (a periodic box without obstacle)
    /// enforcing the boundaries is the identity and skipped.
    pub(super) faces: Arc<Faces>,
    pub(super) diffusion: Arc<Diffusion>,
    pub(super) pressure: Arc<PressureSystem>,
    pub(super) forces: Arc<ForceWeights>,
    pub(super) viscosity: f64,
    pub(super) dt: f64,
    pub(super) inflow: Array1<f64>,
    pub(super) inflow_side: Option<Side>,
    pub(super) buoyancy: Option<Buoyancy>,
    /// The user's body force, if any.
    pub(super) forcing: Option<Arc<dyn Forcing>>,
    pub(super) immersed: Option<Arc<ImmersedCircle>>,
    /// How the immersed body's faces are forced.
    pub(super) immersed_scheme: ForcingScheme,
    pub(super) scalars: usize,
    pub(super) settings: Settings,
    /// The plain forward's buffers, where its caller has no pool current.
    pub(super) buffers: BufferPool,
}

/// A flow scene, built once by [`Scene::builder`]: the grid with its sides
/// and obstacle, the physical parameters, the numerical settings, and what
/// is assembled from them (stencils, the factorised pressure operator).
/// Cloning is cheap (shared).
#[derive(Debug, Clone)]
pub struct Scene(Arc<SceneInner>);

impl Scene {
    /// The grid.
    pub fn grid(&self) -> &FlowGrid {
        &self.0.grid
    }

    /// The solid cells (`[nx, ny]`).
    pub fn solid(&self) -> &Array2<bool> {
        &self.0.solid
    }

    /// The time step.
    pub fn dt(&self) -> f64 {
        self.0.dt
    }

    /// The default viscosity.
    pub fn viscosity(&self) -> f64 {
        self.0.viscosity
    }

    /// The numerical settings.
    pub fn settings(&self) -> &Settings {
        &self.0.settings
    }

    /// Passive scalars in the state.
    pub fn scalars(&self) -> usize {
        self.0.scalars
    }

    /// The inflow side, if any.
    pub fn inflow_side(&self) -> Option<Side> {
        self.0.inflow_side
    }

    /// The length of the inflow profile (0 without an inflow side).
    pub fn inflow_len(&self) -> usize {
        self.0.inflow.len()
    }

    /// Whether the pressure operator is singular (no outflow side).
    pub fn pressure_is_singular(&self) -> bool {
        self.0.pressure.is_singular()
    }

    /// The condition on every face (the sides and the obstacle resolved):
    /// what [`crate::boundaries::enforce_boundaries`], the advection, the
    /// buoyancy and the pressure gradient take.
    pub fn faces(&self) -> &Arc<Faces> {
        &self.0.faces
    }

    /// The viscous operator, for [`crate::diffusion::diffuse`].
    pub fn diffusion(&self) -> &Arc<Diffusion> {
        &self.0.diffusion
    }

    /// The pressure system, for [`crate::pressure::project`].
    pub fn pressure_system(&self) -> &Arc<PressureSystem> {
        &self.0.pressure
    }

    /// The obstacle's surface, for [`crate::diagnostics::obstacle_force`].
    pub fn force_weights(&self) -> &Arc<ForceWeights> {
        &self.0.forces
    }

    /// The parameters the scene was built with (viscosity, wall speeds of its
    /// moving walls, inflow profile).
    pub fn params<T: Real>(&self) -> FlowParams<T> {
        let speed = |s: Side| self.0.grid.sides.get(s).wall_speed();
        FlowParams {
            viscosity: T::from_f64(self.0.viscosity),
            wall_speed: Side::ALL.iter().map(|&s| T::from_f64(speed(s))).collect(),
            inflow: self.0.inflow.mapv(T::from_f64),
        }
    }

    /// `max |u_x| dt/dx + … `: the Courant number `max(|u_x|/dx, |u_y|/dy) · dt`.
    pub fn courant<T: Real>(&self, ux: ArrayView2<'_, T>, uy: ArrayView2<'_, T>, dt: f64) -> f64 {
        let m = |a: ArrayView2<'_, T>, h: f64| max_abs(a) / h;
        dt * m(ux, self.grid().dx).max(m(uy, self.grid().dy))
    }

    /// Checks a state and parameters and picks the number of substeps.
    fn plan<T: Real>(&self, s: &StateView<'_, T>, p: &FlowParams<T>) -> Result<(usize, f64)> {
        const STEP: &str = "flow step";
        let grid = self.grid();
        grid.check_velocity(STEP, s.ux, s.uy)?;
        grid.check_cells(STEP, "pressure", s.pressure)?;
        if s.scalars.len() != self.scalars() {
            return Err(FlowError::shape(
                STEP,
                "scalar list",
                &[self.scalars()],
                &[s.scalars.len()],
            ));
        }
        for a in &s.scalars {
            grid.check_cells(STEP, "scalar", *a)?;
        }
        grid.check_walls(STEP, p.wall_speed.view())?;
        self.faces().check_inflow(STEP, p.inflow.view())?;
        let finite = |quantity: &str, count: usize| -> Result<()> {
            if count == 0 {
                Ok(())
            } else {
                Err(FlowError::NonFinite {
                    step: STEP.into(),
                    quantity: quantity.into(),
                    count,
                })
            }
        };
        finite("x-velocity", nonfinite(s.ux.iter()))?;
        finite("y-velocity", nonfinite(s.uy.iter()))?;
        finite("pressure", nonfinite(s.pressure.iter()))?;
        for a in &s.scalars {
            finite("scalar", nonfinite(a.iter()))?;
        }
        finite("wall speeds", nonfinite(p.wall_speed.iter()))?;
        finite("inflow profile", nonfinite(p.inflow.iter()))?;
        let nu = p.viscosity.as_f64();
        if !(nu.is_finite() && nu > 0.0) {
            return Err(FlowError::parameter(
                STEP,
                "viscosity",
                format!("need a finite viscosity > 0, got {nu}"),
            ));
        }
        let dt = self.dt();
        // The inflow enters the domain too.
        let inflow_max = p.inflow.iter().fold(0.0f64, |m, v| m.max(v.as_f64().abs()));
        let h = grid.dx.min(grid.dy);
        let courant = self.courant(s.ux, s.uy, dt).max(inflow_max * dt / h);
        let limit = self.settings().max_courant;
        let mut n = 1;
        if courant > limit {
            if !self.settings().substepping {
                return Err(FlowError::Cfl {
                    step: "advection".into(),
                    quantity: "Courant".into(),
                    number: courant,
                    limit,
                });
            }
            n = (courant / limit).ceil() as usize;
        }
        if self.settings().viscosity_mode == ViscosityMode::Explicit {
            let d = explicit_diffusion_number(grid, nu, dt);
            if d > 0.5 {
                if !self.settings().substepping {
                    return Err(FlowError::Cfl {
                        step: "explicit diffusion".into(),
                        quantity: "diffusion".into(),
                        number: d,
                        limit: 0.5,
                    });
                }
                n = n.max((d / 0.5).ceil() as usize);
            }
        }
        Ok((n, courant))
    }

    /// One step on `tape`: every piece recorded as an op, the gradient through
    /// the state and the parameters available by `tape.backward`.
    ///
    /// # Errors
    /// [`FlowError`] naming the piece of the step and the quantity: shapes,
    /// NaN or infinity in the state or parameters, `ν ≤ 0`, a CFL violation
    /// without substepping, a failed pressure or viscosity solve.
    pub fn step<'t, T: Real>(
        &self,
        tape: &'t Tape<T>,
        state: &FlowVars<'t, T>,
        params: &ParamVars<'t, T>,
    ) -> Result<(FlowVars<'t, T>, StepInfo)> {
        let body = self.body_shape().map(|b| tape.constant(b));
        self.step_shaped(tape, state, params, body)
    }

    /// [`Scene::step`] on a scene with an immersed body
    /// ([`SceneBuilder::immersed`]) whose shape `(c_x, c_y, r)` (`[3]`) is
    /// `body`, a tape value: the gradient with respect to the body's centre
    /// and radius is then `tape.backward`'s (see [`crate::immersed`]).
    ///
    /// # Errors
    /// Those of [`Scene::step`]; [`FlowError::InvalidParameter`] on a scene
    /// without an immersed body; those of [`crate::immersed::Circle::from_shape`]
    /// for the body's value.
    pub fn step_with_body<'t, T: Real>(
        &self,
        tape: &'t Tape<T>,
        state: &FlowVars<'t, T>,
        params: &ParamVars<'t, T>,
        body: Var<'t, T>,
    ) -> Result<(FlowVars<'t, T>, StepInfo)> {
        if self.0.immersed.is_none() {
            return Err(FlowError::parameter(
                "flow step",
                "body",
                "the scene has no immersed body (SceneBuilder::immersed)",
            ));
        }
        self.step_shaped(tape, state, params, Some(body))
    }

    /// The immersed body, if the scene has one.
    pub fn immersed(&self) -> Option<&Arc<ImmersedCircle>> {
        self.0.immersed.as_ref()
    }

    /// How the immersed body's faces are forced ([`SceneBuilder::immersed_scheme`]).
    pub fn immersed_scheme(&self) -> ForcingScheme {
        self.0.immersed_scheme
    }

    /// `−impulse / dt`: the force of the flow on the immersed body over a step
    /// whose forcing added `impulse` (see [`StepInfo::immersed_force`]).
    fn immersed_force(&self, impulse: &ForcingImpulse) -> [f64; 2] {
        impulse.total().map(|m| -m / self.dt())
    }

    /// The immersed body's shape `(c_x, c_y, r)` as an array `[3]`.
    fn body_shape<T: Real>(&self) -> Option<ArrayD<T>> {
        self.0.immersed.as_ref().map(|b| {
            let s = b.circle().shape().map(T::from_f64);
            ArrayD::from_shape_vec(IxDyn(&[3]), s.to_vec()).expect("three values")
        })
    }

    fn step_shaped<'t, T: Real>(
        &self,
        tape: &'t Tape<T>,
        state: &FlowVars<'t, T>,
        params: &ParamVars<'t, T>,
        body: Option<Var<'t, T>>,
    ) -> Result<(FlowVars<'t, T>, StepInfo)> {
        // the tape's values, viewed (not copied) for the checks
        let held: Vec<_> = [state.ux, state.uy, state.pressure]
            .iter()
            .chain(&state.scalars)
            .map(|v| v.value())
            .collect();
        fn two<'a, T>(a: &'a ArrayD<T>, what: &str) -> Result<ArrayView2<'a, T>> {
            a.view()
                .into_dimensionality::<Ix2>()
                .map_err(|_| FlowError::shape("flow step", what, &[0, 0], a.shape()))
        }
        let s = StateView {
            ux: two(&held[0], "x-velocity")?,
            uy: two(&held[1], "y-velocity")?,
            pressure: two(&held[2], "pressure")?,
            scalars: held[3..]
                .iter()
                .map(|a| two(a, "scalar"))
                .collect::<Result<_>>()?,
        };
        let p = FlowParams {
            viscosity: params.viscosity.item().map_err(|_| {
                FlowError::shape("flow step", "viscosity", &[], &params.viscosity.shape())
            })?,
            wall_speed: params
                .wall_speed
                .to_array()
                .into_dimensionality()
                .map_err(|_| {
                    FlowError::shape("flow step", "wall speeds", &[4], &params.wall_speed.shape())
                })?,
            inflow: params
                .inflow
                .to_array()
                .into_dimensionality()
                .map_err(|_| {
                    FlowError::shape(
                        "flow step",
                        "inflow profile",
                        &[self.inflow_len()],
                        &params.inflow.shape(),
                    )
                })?,
        };
        let (n, courant) = self.plan(&s, &p)?;
        let exec = OnTape(tape);
        let counter = SolveCounter::new();
        let impulse = ForcingImpulse::new();
        let mut st = StateOf {
            ux: state.ux,
            uy: state.uy,
            pressure: state.pressure,
            scalars: state.scalars.clone(),
        };
        let pv = ParamsOf {
            viscosity: params.viscosity,
            wall_speed: params.wall_speed,
            inflow: params.inflow,
            body,
        };
        for _ in 0..n {
            st = substep(
                &exec,
                self,
                st,
                &pv,
                self.dt() / n as f64,
                &counter,
                &impulse,
            )?;
        }
        let info = StepInfo {
            substeps: n,
            courant,
            pressure_iterations: counter.iterations(),
            immersed_force: self.immersed_force(&impulse),
        };
        Ok((
            FlowVars {
                ux: st.ux,
                uy: st.uy,
                pressure: st.pressure,
                scalars: st.scalars,
            },
            info,
        ))
    }

    /// One step without a tape: the same ops' forwards, no tape memory.
    ///
    /// A step whose kernels split runs whole on a thread of the pool
    /// ([`Scene::on_pool`]), so that its kernels and its pressure solve split
    /// across cores without handing work over at each call; the result is the
    /// same bits on any number of threads.
    ///
    /// Its scratch arrays come from the buffer pool current on the calling
    /// thread, or where none is, from the scene's own (which keeps, of each
    /// length, as many buffers as one step had out at once, and is freed with
    /// the scene): a rollout allocates almost nothing after its first step.
    ///
    /// # Errors
    /// As [`Scene::step`].
    pub fn forward<T: Real>(
        &self,
        state: &FlowState<T>,
        params: &FlowParams<T>,
    ) -> Result<(FlowState<T>, StepInfo)> {
        let pool = BufferPool::current().unwrap_or_else(|| self.0.buffers.clone());
        self.on_pool(|| pool.scope(|| self.forward_here(state, params)))
    }

    /// Whether the step's kernels split across threads: its advection does
    /// from [`crate::advection::PARALLEL_FROM`] entries, the pressure solve
    /// and the tape's kernels from [`parallel::on_pool`]'s length.
    pub(crate) fn splits(&self) -> bool {
        self.grid().nx * self.grid().ny >= crate::advection::PARALLEL_FROM
    }

    /// Runs `f` on a thread of the pool if the step's kernels split there
    /// ([`parallel::to_pool`]), else here: for a caller that records a
    /// rollout on a tape of its own, created inside `f` (a tape stays on the
    /// thread that made it).
    pub fn on_pool<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        if self.splits() {
            parallel::to_pool(f)
        } else {
            f()
        }
    }

    /// [`Scene::forward`] on the calling thread.
    fn forward_here<T: Real>(
        &self,
        state: &FlowState<T>,
        params: &FlowParams<T>,
    ) -> Result<(FlowState<T>, StepInfo)> {
        let (n, courant) = self.plan(&state.view(), params)?;
        let counter = SolveCounter::new();
        let impulse = ForcingImpulse::new();
        let d = |a: &Array2<T>| a.clone().into_dyn();
        let mut st = StateOf {
            ux: d(&state.ux),
            uy: d(&state.uy),
            pressure: d(&state.pressure),
            scalars: state.scalars.iter().map(d).collect(),
        };
        let pv = ParamsOf {
            viscosity: ArrayD::from_elem(IxDyn(&[]), params.viscosity),
            wall_speed: params.wall_speed.clone().into_dyn(),
            inflow: params.inflow.clone().into_dyn(),
            body: self.body_shape(),
        };
        for _ in 0..n {
            st = substep(
                &Plain,
                self,
                st,
                &pv,
                self.dt() / n as f64,
                &counter,
                &impulse,
            )?;
        }
        let two = |a: ArrayD<T>| a.into_dimensionality().expect("the ops return 2D fields");
        Ok((
            FlowState {
                ux: two(st.ux),
                uy: two(st.uy),
                pressure: two(st.pressure),
                scalars: st.scalars.into_iter().map(two).collect(),
            },
            StepInfo {
                substeps: n,
                courant,
                pressure_iterations: counter.iterations(),
                immersed_force: self.immersed_force(&impulse),
            },
        ))
    }

    /// The step as a [`StepFn`] for [`diffphys_tape::checkpointed_steps`]:
    /// state `[u_x, u_y, P, scalars…]` ([`FlowVars::to_vec`]), parameters
    /// `[ν, wall_speed, inflow]` ([`ParamVars::to_vec`]).
    pub fn step_fn<T: Real>(&self) -> Rc<StepFn<T>> {
        let scene = self.clone();
        let f: Rc<StepFn<T>> = Rc::new(move |tape, _k, state, params| {
            let s = FlowVars::from_slice(state).map_err(TapeError::from)?;
            let p = ParamVars::from_slice(params).map_err(TapeError::from)?;
            let (next, _) = scene.step(tape, &s, &p).map_err(TapeError::from)?;
            Ok(next.to_vec())
        });
        f
    }

    /// [`Scene::step_fn`] that records each step's [`StepInfo`] in `log`
    /// under its index (a recomputed step replaces its report).
    pub fn step_fn_logged<T: Real>(&self, log: &StepLog) -> Rc<StepFn<T>> {
        let (scene, log) = (self.clone(), log.clone());
        let f: Rc<StepFn<T>> = Rc::new(move |tape, k, state, params| {
            let s = FlowVars::from_slice(state).map_err(TapeError::from)?;
            let p = ParamVars::from_slice(params).map_err(TapeError::from)?;
            let (next, info) = scene.step(tape, &s, &p).map_err(TapeError::from)?;
            log.record(k, info);
            Ok(next.to_vec())
        });
        f
    }

    /// [`Scene::rollout`] with each step's report in the returned [`StepLog`]:
    /// one report per step however often a checkpointed segment recomputes
    /// it (the log is shared, so it also holds the backward sweep's
    /// recomputations, which replace the reports with equal ones).
    ///
    /// # Errors
    /// As [`Scene::rollout`].
    pub fn rollout_logged<'t, T: Real>(
        &self,
        tape: &'t Tape<T>,
        schedule: Schedule,
        steps: usize,
        state: &FlowVars<'t, T>,
        params: &ParamVars<'t, T>,
    ) -> Result<(FlowVars<'t, T>, StepLog)> {
        let log = StepLog::new();
        let out = checkpointed_steps(
            tape,
            schedule,
            steps,
            &state.to_vec(),
            &params.to_vec(),
            self.step_fn_logged(&log),
        )?;
        Ok((FlowVars::from_slice(&out)?, log))
    }

    /// `steps` steps on `tape`, stored by `schedule` (checkpointed segments
    /// recompute their steps in the backward sweep).
    ///
    /// # Errors
    /// As [`Scene::step`]; errors inside a checkpointed segment come back as
    /// the [`FlowError`] they were.
    pub fn rollout<'t, T: Real>(
        &self,
        tape: &'t Tape<T>,
        schedule: Schedule,
        steps: usize,
        state: &FlowVars<'t, T>,
        params: &ParamVars<'t, T>,
    ) -> Result<FlowVars<'t, T>> {
        let out = checkpointed_steps(
            tape,
            schedule,
            steps,
            &state.to_vec(),
            &params.to_vec(),
            self.step_fn(),
        )?;
        FlowVars::from_slice(&out)
    }
}

impl AsRef<FlowGrid> for Scene {
    fn as_ref(&self) -> &FlowGrid {
        self.grid()
    }
}

/// How many of the values are NaN or infinite.
fn nonfinite<'a, T: Real>(values: impl Iterator<Item = &'a T>) -> usize {
    values.filter(|v| !v.is_finite()).count()
}

/// `max |v|` (0 for none), over eight running maxima so that the loop is not
/// one chain of dependent comparisons.
fn max_abs<T: Real>(a: ArrayView2<'_, T>) -> f64 {
    let mut m = [0.0f64; 8];
    let mut fold = |chunk: &[T]| {
        for (mi, v) in m.iter_mut().zip(chunk) {
            *mi = mi.max(v.as_f64().abs());
        }
    };
    match a.as_slice_memory_order() {
        Some(s) => s.chunks(8).for_each(&mut fold),
        None => a.iter().for_each(|v| fold(std::slice::from_ref(v))),
    }
    m.iter().fold(0.0f64, |x, &y| x.max(y))
}

/// A state's arrays, viewed.
struct StateView<'a, T> {
    ux: ArrayView2<'a, T>,
    uy: ArrayView2<'a, T>,
    pressure: ArrayView2<'a, T>,
    scalars: Vec<ArrayView2<'a, T>>,
}

impl<T: Real> FlowState<T> {
    fn view(&self) -> StateView<'_, T> {
        StateView {
            ux: self.ux.view(),
            uy: self.uy.view(),
            pressure: self.pressure.view(),
            scalars: self.scalars.iter().map(|a| a.view()).collect(),
        }
    }
}
