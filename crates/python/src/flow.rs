//! The 2D incompressible flow step of `diffphys_flow` (MAC velocity,
//! advection, viscosity, projection with an obstacle, per-side boundaries) on
//! numpy arrays, with its vector–Jacobian product through `steps` steps.

use diffphys_flow::diagnostics::{obstacle_force, ObstacleForce};
use diffphys_flow::{
    Advection, Boundary, Circle, FlowParams, FlowState, FlowVars, ForcingScheme, Interior,
    Obstacle, ParamVars, PressureSolver, Scene, Sides, Splitting, ViscosityMode,
};
use diffphys_tape::pool::BufferPool;
use diffphys_tape::{ArrayD, Real, Schedule, Tape, Var};
use ndarray::{Array2, Ix1, Ix2, IxDyn};
use numpy::{Element, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::arrays::{dtype_of, to_numpy, view, Dtype};
use crate::errors::{check, InvalidArgumentError, ShapeError};

/// A flow scene and its step: `(u, P) ↦ (u', P')`, `steps` times, and the
/// force `[drag, lift]` of the flow on the obstacle at the end.
///
/// One step (`diffphys_flow::step`): self-advection of the MAC velocity
/// (semi-Lagrangian or MacCormack), viscosity (explicit or implicit), the
/// boundaries of each side, and the pressure projection with the obstacle
/// (the incremental splitting by default). Its VJP records the steps on a
/// tape (checkpointed every `⌈√steps⌉` steps) and runs the reverse sweep:
/// every piece has a hand-written adjoint, the projection's is one more
/// pressure solve.
///
/// Constructor: `FlowStep(shape, size, *, sides="periodic", obstacle=None,
/// viscosity=0.01, dt=0.01, inflow=None, advection="semi_lagrangian",
/// viscosity_mode="explicit", pressure_solver="cholesky",
/// pressure_rel_tol=1e-10, splitting="incremental", substepping=False,
/// max_courant=1.0, buffer_limit_bytes=2**31, immersed=None,
/// immersed_interior="solid", immersed_scheme="direct")`. `shape` is the cells
/// `(nx, ny)`, `size` the domain `(lx, ly)`; `obstacle` a bool array of the cell shape (true: solid);
/// `immersed` a circle `(cx, cy, r)` as a direct-forcing immersed boundary
/// (`diffphys_flow::immersed`, in place of `obstacle`): the free faces next
/// to it are forced by interpolation to the true wall; `immersed_interior`
/// `"solid"` (the circle's cells solid, as `obstacle` would make them) or
/// `"forced"` (no solid cell, the faces inside the circle forced to zero);
/// `immersed_scheme` `"direct"` or `"consistent"` (the projection-consistent
/// forcing);
/// `sides` a preset (`"periodic"`, `"channel"`, `"cavity"`, or one side
/// condition for all four) or a dict `{"left": …, "right": …, "bottom": …,
/// "top": …}` of `"no_slip"`, `"free_slip"`, `"periodic"`, `"inflow"`,
/// `"outflow"` or `("moving", speed)` (missing sides no-slip);
/// `inflow` a speed (uniform) or a profile along the inflow side;
/// `pressure_solver` `"cholesky"`, `"fourier"` (a box periodic in both
/// axes without obstacle), `"cg"` or `"multigrid"`. `vjp` keeps the
/// buffers of its tape for the next call, up to `buffer_limit_bytes`
/// (0: none): fresh memory is faulted in page by page, about a third of
/// a 100-step VJP's time at 256² (`held_bytes`, `release_buffers`).
///
/// Shapes and dtypes: `ux` is `shape_x` (the x-faces), `uy` is `shape_y`
/// (the y-faces), the pressure is `shape` (the cells `(nx, ny)`), the force
/// is `(2,)`; all float32 or float64 of one dtype, results in that dtype.
///
/// The force: on an `obstacle`, the surface integral of pressure and wall
/// shear over the staircase at the end state, differentiable (`grad_force`).
/// On an `immersed` circle, the momentum exchange of the immersed boundary
/// method: minus the forcing's momentum per unit time over the last step
/// (`StepInfo::immersed_force`, the whole force with a forced interior), plus
/// with a solid interior the staircase's surface integral at the end state.
/// The forcing's exchange is not recorded on the tape, so `vjp` refuses a
/// `grad_force` seed on an immersed scene: a force by the momentum balance
/// over a box about the body is a function of the state, whose gradient
/// goes in through `grad_ux`, `grad_uy` and `grad_pressure`.
///
/// Raises: `InvalidArgumentError` (an unknown side, advection, solver,
/// splitting, immersed interior or scheme name, a non-positive `dt` or
/// viscosity, `steps=0`, an inflow profile of the wrong length, an obstacle
/// and an immersed circle together, a circle of radius ≤ 0, `grad_force` on
/// an immersed circle), `ShapeError` (arrays not of the grid's
/// shapes, an obstacle not of the cell shape), `TypeError` (not float arrays,
/// an obstacle not a bool array), `NonFiniteError` (NaN or infinity in the
/// state), `UnstableError` (a Courant number above `max_courant` without
/// `substepping`), `NotConvergedError` (an iterative pressure solve).
///
/// >>> import numpy as np, diffphys as dp
/// >>> scene = dp.FlowStep((32, 32), (1.0, 1.0), viscosity=0.01, dt=0.01)
/// >>> ux, uy = np.zeros(scene.shape_x), np.zeros(scene.shape_y)
/// >>> ux2, uy2, p, force = scene.forward(ux, uy, steps=10)
#[pyclass(module = "diffphys._native", frozen)]
pub struct FlowStep {
    scene: Scene,
    /// The buffers of the last `vjp` (its tape's values and gradients),
    /// reused by the next: this object's memory, freed with it or by
    /// `release_buffers`.
    buffers: BufferPool,
}

/// What a `FlowStep` keeps between `vjp` calls unless told otherwise: 2 GiB,
/// four times what a 100-step VJP at 256² in f64 records (474 MB), so a
/// pool never holds more than the last call needed and the limit only
/// guards against much larger grids.
const DEFAULT_BUFFER_LIMIT: usize = 2 << 30;

/// One side's condition by name: `"no_slip"`, `"free_slip"`, `"periodic"`,
/// `"inflow"`, `"outflow"`, or `("moving", speed)`.
fn side(obj: &Bound<'_, PyAny>) -> PyResult<Boundary> {
    if let Ok((name, speed)) = obj.extract::<(String, f64)>() {
        return match name.as_str() {
            "moving" | "moving_wall" => Ok(Boundary::moving_wall(speed)),
            other => Err(InvalidArgumentError::new_err(format!(
                "a side given as (name, speed) must be (\"moving\", speed), got {other:?}"
            ))),
        };
    }
    let name: String = obj
        .extract()
        .map_err(|_| PyTypeError::new_err("a side is a name or (\"moving\", speed)"))?;
    match name.as_str() {
        "no_slip" | "wall" => Ok(Boundary::no_slip()),
        "free_slip" => Ok(Boundary::free_slip()),
        "periodic" => Ok(Boundary::periodic()),
        "inflow" => Ok(Boundary::inflow()),
        "outflow" => Ok(Boundary::outflow()),
        other => Err(InvalidArgumentError::new_err(format!(
            "unknown side condition {other:?}: use \"no_slip\", \"free_slip\", \"periodic\", \
             \"inflow\", \"outflow\" or (\"moving\", speed)"
        ))),
    }
}

/// `sides=`: a preset (`"periodic"`, `"channel"`, `"cavity"`, or any side
/// condition on all four sides) or a dict `{"left": …, "right": …,
/// "bottom": …, "top": …}` (missing sides no-slip).
fn sides(obj: &Bound<'_, PyAny>) -> PyResult<Sides> {
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut s = Sides::all(Boundary::no_slip());
        for (k, v) in d.iter() {
            let b = side(&v)?;
            match k.extract::<String>()?.as_str() {
                "left" => s.left = b,
                "right" => s.right = b,
                "bottom" => s.bottom = b,
                "top" => s.top = b,
                other => {
                    return Err(InvalidArgumentError::new_err(format!(
                        "unknown side {other:?}: use left, right, bottom, top"
                    )))
                }
            }
        }
        return Ok(s);
    }
    match obj.extract::<String>().ok().as_deref() {
        Some("channel") => Ok(Sides::channel()),
        Some("cavity") => Ok(Sides::cavity(1.0)),
        _ => Ok(Sides::all(side(obj)?)),
    }
}

#[pymethods]
impl FlowStep {
    /// The constructor (its arguments are described on the class).
    #[new]
    #[pyo3(signature = (
        shape, size, *, sides = None, obstacle = None, viscosity = 0.01, dt = 0.01,
        inflow = None, advection = "semi_lagrangian", viscosity_mode = "explicit",
        pressure_solver = "cholesky", pressure_rel_tol = 1e-10, splitting = "incremental",
        substepping = false, max_courant = 1.0, buffer_limit_bytes = DEFAULT_BUFFER_LIMIT,
        immersed = None, immersed_interior = "solid", immersed_scheme = "direct"
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        shape: (usize, usize),
        size: (f64, f64),
        sides: Option<&Bound<'_, PyAny>>,
        obstacle: Option<&Bound<'_, PyAny>>,
        viscosity: f64,
        dt: f64,
        inflow: Option<&Bound<'_, PyAny>>,
        advection: &str,
        viscosity_mode: &str,
        pressure_solver: &str,
        pressure_rel_tol: f64,
        splitting: &str,
        substepping: bool,
        max_courant: f64,
        buffer_limit_bytes: usize,
        immersed: Option<(f64, f64, f64)>,
        immersed_interior: &str,
        immersed_scheme: &str,
    ) -> PyResult<Self> {
        let sides = match sides {
            Some(s) => self::sides(s)?,
            None => Sides::periodic(),
        };
        let mut b = Scene::builder(shape.0, shape.1, [size.0, size.1])
            .sides(sides)
            .viscosity(viscosity)
            .dt(dt)
            .substepping(substepping)
            .max_courant(max_courant)
            .advection(match advection {
                "semi_lagrangian" => Advection::SemiLagrangian,
                "maccormack" => Advection::MacCormack { limiter: true },
                other => return Err(unknown("advection", other, "semi_lagrangian, maccormack")),
            })
            .viscosity_mode(match viscosity_mode {
                "explicit" => ViscosityMode::Explicit,
                "implicit" => ViscosityMode::Implicit,
                other => return Err(unknown("viscosity_mode", other, "explicit, implicit")),
            })
            .pressure_solver(match pressure_solver {
                "cholesky" => PressureSolver::Cholesky,
                "fourier" => PressureSolver::Fourier,
                "cg" => PressureSolver::Cg {
                    rel_tol: pressure_rel_tol,
                    max_iters: 100_000,
                },
                "multigrid" => PressureSolver::MultigridCg {
                    rel_tol: pressure_rel_tol,
                    max_iters: 10_000,
                    sweeps: 2,
                },
                other => {
                    return Err(unknown(
                        "pressure_solver",
                        other,
                        "cholesky, fourier, cg, multigrid",
                    ))
                }
            })
            .splitting(match splitting {
                "incremental" => Splitting::Incremental,
                "plain" => Splitting::Plain,
                other => return Err(unknown("splitting", other, "incremental, plain")),
            });
        if let Some(solid) = obstacle {
            let solid = solid
                .extract::<PyReadonlyArrayDyn<'_, bool>>()
                .map_err(|_| PyTypeError::new_err("obstacle must be a numpy array of bool"))?;
            let mask = solid
                .as_array()
                .to_owned()
                .into_dimensionality::<Ix2>()
                .map_err(|_| ShapeError::new_err("obstacle must be a 2D array"))?;
            b = b.obstacle(Obstacle::Mask(mask));
        }
        if let Some((cx, cy, r)) = immersed {
            if obstacle.is_some() {
                return Err(InvalidArgumentError::new_err(
                    "the flow step takes an obstacle or an immersed circle, not both",
                ));
            }
            b = b
                .immersed(check(Circle::new([cx, cy], r))?)
                .immersed_interior(match immersed_interior {
                    "solid" => Interior::Solid,
                    "forced" => Interior::Forced,
                    other => return Err(unknown("immersed_interior", other, "solid, forced")),
                })
                .immersed_scheme(match immersed_scheme {
                    "direct" => ForcingScheme::Direct,
                    "consistent" => ForcingScheme::ProjectionConsistent,
                    other => return Err(unknown("immersed_scheme", other, "direct, consistent")),
                });
        }
        if let Some(inflow) = inflow {
            b = match inflow.extract::<f64>() {
                Ok(speed) => b.uniform_inflow(speed),
                Err(_) => b.inflow(inflow.extract::<Vec<f64>>()?),
            };
        }
        Ok(FlowStep {
            scene: check(b.build())?,
            buffers: BufferPool::with_limit_bytes(buffer_limit_bytes),
        })
    }

    /// Bytes of buffers kept from the last `vjp` for the next.
    #[getter]
    fn held_bytes(&self) -> usize {
        self.buffers.held_bytes()
    }

    /// Returns the kept buffers to the allocator (the next `vjp` starts
    /// from fresh memory).
    fn release_buffers(&self) {
        self.buffers.clear();
    }

    /// The cells `(nx, ny)`.
    #[getter]
    fn shape(&self) -> (usize, usize) {
        let [a, b] = self.scene.grid().cell_shape();
        (a, b)
    }

    /// The shape of `ux` (x-faces).
    #[getter]
    fn shape_x(&self) -> (usize, usize) {
        let [a, b] = self.scene.grid().shape_x();
        (a, b)
    }

    /// The shape of `uy` (y-faces).
    #[getter]
    fn shape_y(&self) -> (usize, usize) {
        let [a, b] = self.scene.grid().shape_y();
        (a, b)
    }

    /// The time step.
    #[getter]
    fn dt(&self) -> f64 {
        self.scene.dt()
    }

    /// The viscosity the scene was built with.
    #[getter]
    fn viscosity(&self) -> f64 {
        self.scene.viscosity()
    }

    /// The length of the inflow profile (0 without an inflow side).
    #[getter]
    fn inflow_len(&self) -> usize {
        self.scene.inflow_len()
    }

    /// The solid cells (bool, cell shape).
    #[getter]
    fn solid<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        to_numpy(py, self.scene.solid().clone())
    }

    /// `(ux', uy', P', force)` after `steps` steps from `(ux, uy)` and the
    /// pressure `pressure` (zero if None); `viscosity`, `wall_speed` (4, in
    /// the order left, right, bottom, top) and `inflow` default to the
    /// scene's. `force` is `[drag, lift]` on the obstacle at the end.
    ///
    /// `ux`: `shape_x`, `uy`: `shape_y`, `pressure`: `shape`, float32 or
    /// float64; `wall_speed`: `(4,)`, `inflow`: `(inflow_len,)`, the same
    /// dtype. Returns `(ux', uy', P', force)` of those shapes and `(2,)`.
    ///
    /// Raises `InvalidArgumentError` (`steps=0`), `ShapeError`, `TypeError`,
    /// `NonFiniteError`, `UnstableError`, `NotConvergedError`.
    #[pyo3(signature = (ux, uy, *, steps = 1, pressure = None, viscosity = None,
                        wall_speed = None, inflow = None))]
    #[allow(clippy::too_many_arguments)]
    fn forward<'py>(
        &self,
        ux: &Bound<'py, PyAny>,
        uy: &Bound<'py, PyAny>,
        steps: usize,
        pressure: Option<&Bound<'py, PyAny>>,
        viscosity: Option<f64>,
        wall_speed: Option<&Bound<'py, PyAny>>,
        inflow: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let args = Args {
            steps,
            pressure,
            viscosity,
            wall_speed,
            inflow,
        };
        match dtype_of(ux, "ux")? {
            Dtype::F32 => self.forward_t::<f32>(ux, uy, &args),
            Dtype::F64 => self.forward_t::<f64>(ux, uy, &args),
        }
    }

    /// The VJP of `forward`: from the gradients of its outputs (`grad_ux`,
    /// `grad_uy`, `grad_pressure`, `grad_force`; None is zero), `(∂L/∂ux,
    /// ∂L/∂uy, ∂L/∂P, ∂L/∂viscosity, ∂L/∂wall_speed, ∂L/∂inflow)`, by
    /// recording the steps on a tape and one reverse sweep.
    /// `checkpoint_every=k` keeps the state of every k-th step and recomputes
    /// the others in the reverse sweep (1: keep every step, the fastest and
    /// the most memory); the default is about √steps.
    ///
    /// The seeds have the shapes of the outputs (`shape_x`, `shape_y`,
    /// `shape`, `(2,)`) and the dtype of `ux`; the gradients are arrays of
    /// the inputs' shapes, `∂L/∂viscosity` a float, `∂L/∂wall_speed` `(4,)`,
    /// `∂L/∂inflow` `(inflow_len,)`.
    ///
    /// Raises `InvalidArgumentError` (`steps=0`, `checkpoint_every=0`,
    /// `grad_force` on an immersed circle), `ShapeError` (a seed not of its output's shape), `TypeError`,
    /// `NonFiniteError`, `UnstableError`, `NotConvergedError`.
    #[pyo3(signature = (ux, uy, grad_ux = None, grad_uy = None, grad_pressure = None,
                        grad_force = None, *, steps = 1, pressure = None, viscosity = None,
                        wall_speed = None, inflow = None, checkpoint_every = None))]
    #[allow(clippy::too_many_arguments)]
    fn vjp<'py>(
        &self,
        ux: &Bound<'py, PyAny>,
        uy: &Bound<'py, PyAny>,
        grad_ux: Option<&Bound<'py, PyAny>>,
        grad_uy: Option<&Bound<'py, PyAny>>,
        grad_pressure: Option<&Bound<'py, PyAny>>,
        grad_force: Option<&Bound<'py, PyAny>>,
        steps: usize,
        pressure: Option<&Bound<'py, PyAny>>,
        viscosity: Option<f64>,
        wall_speed: Option<&Bound<'py, PyAny>>,
        inflow: Option<&Bound<'py, PyAny>>,
        checkpoint_every: Option<usize>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        if checkpoint_every == Some(0) {
            return Err(InvalidArgumentError::new_err(
                "invalid checkpoint_every in the flow step's vjp: need at least 1 (1 keeps every step)",
            ));
        }
        let args = Args {
            steps,
            pressure,
            viscosity,
            wall_speed,
            inflow,
        };
        if grad_force.is_some() && self.scene.immersed().is_some() {
            return Err(InvalidArgumentError::new_err(
                "grad_force on an immersed circle: the forcing's momentum exchange is not on the \
                 tape; seed a force of the state (a momentum balance over a box) through \
                 grad_ux, grad_uy and grad_pressure",
            ));
        }
        let seeds = [grad_ux, grad_uy, grad_pressure, grad_force];
        match dtype_of(ux, "ux")? {
            Dtype::F32 => self.vjp_t::<f32>(ux, uy, seeds, &args, checkpoint_every),
            Dtype::F64 => self.vjp_t::<f64>(ux, uy, seeds, &args, checkpoint_every),
        }
    }
}

fn unknown(what: &str, found: &str, valid: &str) -> PyErr {
    InvalidArgumentError::new_err(format!("unknown {what} {found:?}: use one of {valid}"))
}

/// The keyword arguments of `forward` and `vjp` past the velocity.
struct Args<'a, 'py> {
    steps: usize,
    pressure: Option<&'a Bound<'py, PyAny>>,
    viscosity: Option<f64>,
    wall_speed: Option<&'a Bound<'py, PyAny>>,
    inflow: Option<&'a Bound<'py, PyAny>>,
}

/// An array argument as an owned `Array<T, D>`, checked for its dimension.
fn owned<T: Element + Real, D: ndarray::Dimension>(
    a: &Bound<'_, PyAny>,
    what: &str,
) -> PyResult<ndarray::Array<T, D>> {
    let v = view::<T>(a, what)?;
    let shape = v.shape().to_vec();
    v.as_array()
        .to_owned()
        .into_dimensionality::<D>()
        .map_err(|_| {
            ShapeError::new_err(format!(
                "{what} has shape {shape:?}, not of the dimension the flow step needs"
            ))
        })
}

impl FlowStep {
    /// The state and parameters of a call.
    fn inputs<T: Element + Real>(
        &self,
        ux: &Bound<'_, PyAny>,
        uy: &Bound<'_, PyAny>,
        args: &Args<'_, '_>,
    ) -> PyResult<(FlowState<T>, FlowParams<T>)> {
        let g = self.scene.grid();
        let cells = g.cell_shape();
        let pressure = match args.pressure {
            Some(p) => owned::<T, Ix2>(p, "pressure")?,
            None => Array2::zeros((cells[0], cells[1])),
        };
        let state = FlowState {
            ux: owned::<T, Ix2>(ux, "ux")?,
            uy: owned::<T, Ix2>(uy, "uy")?,
            pressure,
            scalars: Vec::new(),
        };
        let mut params = self.scene.params::<T>();
        if let Some(nu) = args.viscosity {
            params.viscosity = T::from_f64(nu);
        }
        if let Some(w) = args.wall_speed {
            params.wall_speed = owned::<T, Ix1>(w, "wall_speed")?;
        }
        if let Some(q) = args.inflow {
            params.inflow = owned::<T, Ix1>(q, "inflow")?;
        }
        if args.steps == 0 {
            return Err(InvalidArgumentError::new_err("steps must be at least 1"));
        }
        Ok((state, params))
    }

    fn forward_t<'py, T: Real + Element>(
        &self,
        ux: &Bound<'py, PyAny>,
        uy: &Bound<'py, PyAny>,
        args: &Args<'_, 'py>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let py = ux.py();
        let (state, params) = self.inputs::<T>(ux, uy, args)?;
        let scene = &self.scene;
        let steps = args.steps;
        let (end, force) = check(py.detach(|| {
            scene.on_pool(|| {
                let mut s = state;
                let mut exchange = [0.0; 2];
                for _ in 0..steps {
                    let (next, info) = scene.forward(&s, &params)?;
                    (s, exchange) = (next, info.immersed_force);
                }
                let mut f = obstacle_force(
                    scene.force_weights(),
                    s.ux.view(),
                    s.uy.view(),
                    s.pressure.view(),
                    params.viscosity,
                )?;
                // an immersed body's force is the forcing's exchange over
                // the last step (zero on a scene without one), see the class
                for (a, e) in f.iter_mut().zip(exchange) {
                    *a += T::from_f64(e);
                }
                Ok::<_, diffphys_flow::FlowError>((s, f))
            })
        }))?;
        PyTuple::new(
            py,
            [
                to_numpy(py, end.ux),
                to_numpy(py, end.uy),
                to_numpy(py, end.pressure),
                to_numpy(py, force),
            ],
        )
    }

    fn vjp_t<'py, T: Real + Element>(
        &self,
        ux: &Bound<'py, PyAny>,
        uy: &Bound<'py, PyAny>,
        seeds: [Option<&Bound<'py, PyAny>>; 4],
        args: &Args<'_, 'py>,
        checkpoint_every: Option<usize>,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let py = ux.py();
        let (state, params) = self.inputs::<T>(ux, uy, args)?;
        let names = ["grad_ux", "grad_uy", "grad_pressure", "grad_force"];
        let mut g: [Option<ArrayD<T>>; 4] = Default::default();
        let grid = self.scene.grid();
        let want = [
            grid.shape_x().to_vec(),
            grid.shape_y().to_vec(),
            grid.cell_shape().to_vec(),
            vec![2],
        ];
        for (k, seed) in seeds.iter().enumerate() {
            if let Some(s) = seed {
                let a = view::<T>(s, names[k])?.as_array().to_owned();
                if a.shape() != want[k].as_slice() {
                    return Err(ShapeError::new_err(format!(
                        "shape mismatch in the flow step's vjp: {} has shape {:?}, the output has {:?}",
                        names[k],
                        a.shape(),
                        want[k]
                    )));
                }
                g[k] = Some(a);
            }
        }
        let scene = &self.scene;
        let steps = args.steps;
        let buffers = &self.buffers;
        // The tape is made and dropped on a pool thread when the step splits
        // across cores (Scene::on_pool): its kernels then split cheaply.
        let grads = check(py.detach(|| {
            scene.on_pool(|| {
                let tape = Tape::<T>::with_pool(buffers);
                vjp_on_tape(&tape, scene, state, params, g, steps, checkpoint_every)
            })
        }))?;
        let [gux, guy, gp, gnu, gw, gq] = grads;
        let nu = gnu.first().copied().unwrap_or_else(T::zero).as_f64();
        let items = vec![
            to_numpy(py, gux),
            to_numpy(py, guy),
            to_numpy(py, gp),
            nu.into_pyobject(py)?.into_any(),
            to_numpy(py, gw),
            to_numpy(py, gq),
        ];
        PyTuple::new(py, items)
    }
}

/// Records `steps` steps and the force on a tape, seeds `Σ g·outputs`, and
/// returns the gradients with respect to `[ux, uy, P, ν, wall_speed, inflow]`
/// (zeros where the loss does not reach).
fn vjp_on_tape<T: Real>(
    tape: &Tape<T>,
    scene: &Scene,
    state: FlowState<T>,
    params: FlowParams<T>,
    seeds: [Option<ArrayD<T>>; 4],
    steps: usize,
    checkpoint_every: Option<usize>,
) -> Result<[ArrayD<T>; 6], diffphys_flow::FlowError> {
    let vars = FlowVars {
        ux: tape.var(state.ux),
        uy: tape.var(state.uy),
        pressure: tape.var(state.pressure),
        scalars: Vec::new(),
    };
    let pv = ParamVars {
        viscosity: tape.var(ArrayD::from_elem(IxDyn(&[]), params.viscosity)),
        wall_speed: tape.var(params.wall_speed),
        inflow: tape.var(params.inflow),
    };
    let every = checkpoint_every.unwrap_or((steps as f64).sqrt().ceil() as usize);
    let schedule = if steps <= 2 || every <= 1 {
        Schedule::Full
    } else {
        Schedule::Every(every)
    };
    let end = scene.rollout(tape, schedule, steps, &vars, &pv)?;
    let force = tape.apply(
        ObstacleForce {
            weights: scene.force_weights().clone(),
        },
        &[end.ux, end.uy, end.pressure, pv.viscosity],
    )?;
    let outputs = [end.ux, end.uy, end.pressure, force];
    let mut loss: Option<Var<'_, T>> = None;
    for (seed, out) in seeds.into_iter().zip(outputs) {
        if let Some(seed) = seed {
            let term = tape.constant(seed).mul(out)?.sum()?;
            loss = Some(match loss {
                Some(l) => l.add(term)?,
                None => term,
            });
        }
    }
    let wrt = [
        vars.ux,
        vars.uy,
        vars.pressure,
        pv.viscosity,
        pv.wall_speed,
        pv.inflow,
    ];
    let zeros = |v: &Var<'_, T>| ArrayD::zeros(IxDyn(&v.shape()));
    let Some(loss) = loss else {
        return Ok(wrt.map(|v| zeros(&v)));
    };
    let grads = tape.backward(loss, &wrt)?;
    Ok(wrt.map(|v| grads.get(v).cloned().unwrap_or_else(|| zeros(&v))))
}
