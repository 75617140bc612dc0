//! Flow around a cylinder in a channel: the DFG benchmark of Schäfer and
//! Turek (1996), test cases 2D-1 (Re = 20, steady) and 2D-2 (Re = 100,
//! periodic).
//!
//! The channel is 2.2 × 0.41, the cylinder of diameter D = 0.1 is centred at
//! (0.2, 0.2), ν = 1e-3, density 1; parabolic inflow of peak Um on the left,
//! outflow on the right, no-slip walls and cylinder. [`DfgChannel`] puts
//! `cpd` square cells across the diameter (h = D / cpd) and the cylinder is a
//! staircase of solid cells; MacCormack advection with the limiter at
//! Courant number 0.4 of Um, explicit viscosity where stable (implicit
//! otherwise), substepping on.
//!
//! - 2D-1 ([`Dfg2d1`]): from the inflow profile carried through the channel,
//!   run until no face changes by more than `tol` per unit time; drag and
//!   lift coefficients `cD = 2 F_x / (Ubar² D)`, `cL = 2 F_y / (Ubar² D)`
//!   (the body's own force, [`DfgChannel::body_force`]: the surface force on
//!   the staircase, the momentum exchange of an immersed body's forcing)
//!   and `dp = p(0.15, 0.2) − p(0.25, 0.2)`.
//!   The drag and lift are also reported by the momentum balance over a
//!   square around the body ([`DfgChannel::control_box`],
//!   [`control_volume_force`]), which never reads the staircase.
//! - 2D-2 ([`Dfg2d2`]): from the same start to `t_end`; over the last
//!   `window` time units the largest cD and cL and the Strouhal number
//!   `St = D f / Ubar` from the period of the lift (its up-crossings of the
//!   mean); the largest cD and cL also by the momentum balance, its time
//!   term from successive states.
//!
//! # References
//! M. Schäfer and S. Turek, *Benchmark computations of laminar flow around a
//! cylinder*, in Flow Simulation with High-Performance Computers II, Notes on
//! Numerical Fluid Mechanics 52 (1996) 547–566: the problem (section 2) and
//! the reference intervals of Table 4, the ranges the best participating
//! codes' results lay in. V. John and G. Matthies, *Higher-order finite
//! element discretizations in a benchmark problem for incompressible flows*,
//! Int. J. Numer. Meth. Fluids 37 (2001) 885–903, and E. Nabh (1998): the
//! later high-accuracy 2D-1 values.

use ndarray::Array2;

use crate::advection::Advection;
use crate::boundaries::{Obstacle, Sides};
use crate::diffusion::ViscosityMode;
use crate::immersed::{Circle, ForcingScheme, Interior};
use crate::{FlowError, FlowState, Result, Scene};

use super::{control_volume_force, FaceBox, Shedding};
use super::{positive, run_to_steady, FloorCheck, Interval, Observer, SteadyRun, SteadyStop};

/// The channel's length.
pub const DFG_LENGTH: f64 = 2.2;
/// The channel's height (the cylinder sits 0.005 below its middle, which
/// makes the lift non-zero).
pub const DFG_HEIGHT: f64 = 0.41;
/// The cylinder's centre.
pub const DFG_CENTRE: [f64; 2] = [0.2, 0.2];
/// The cylinder's diameter `D`.
pub const DFG_DIAMETER: f64 = 0.1;
/// The kinematic viscosity `ν` (density 1).
pub const DFG_NU: f64 = 1e-3;

/// The published figures of test case 2D-1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dfg2d1Reference {
    /// The inflow's peak `Um`.
    pub um: f64,
    /// The mean inflow `Ubar = 2 Um / 3`; `Re = Ubar D / ν`.
    pub ubar: f64,
    /// The drag coefficient.
    pub cd: Interval,
    /// The lift coefficient.
    pub cl: Interval,
    /// The pressure difference front − back.
    pub dp: Interval,
}

/// The published figures of test case 2D-2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dfg2d2Reference {
    /// The inflow's peak `Um`.
    pub um: f64,
    /// The mean inflow `Ubar`.
    pub ubar: f64,
    /// The Strouhal number of the lift.
    pub strouhal: Interval,
    /// The largest drag coefficient over a period.
    pub cd_max: Interval,
    /// The largest lift coefficient over a period.
    pub cl_max: Interval,
    /// dp half a period after the lift's maximum.
    pub dp_half_period: Interval,
}

/// 2D-1 (Re = 20, steady): Schäfer and Turek 1996, Table 4.
pub const DFG_2D1: Dfg2d1Reference = Dfg2d1Reference {
    um: 0.3,
    ubar: 0.2,
    cd: Interval { lo: 5.57, hi: 5.59 },
    cl: Interval {
        lo: 0.0104,
        hi: 0.0110,
    },
    dp: Interval {
        lo: 0.1172,
        hi: 0.1176,
    },
};

/// 2D-2 (Re = 100, periodic): Schäfer and Turek 1996, Table 4.
pub const DFG_2D2: Dfg2d2Reference = Dfg2d2Reference {
    um: 1.5,
    ubar: 1.0,
    strouhal: Interval {
        lo: 0.295,
        hi: 0.305,
    },
    cd_max: Interval { lo: 3.22, hi: 3.24 },
    cl_max: Interval { lo: 0.99, hi: 1.01 },
    dp_half_period: Interval { lo: 2.46, hi: 2.50 },
};

/// The later high-accuracy 2D-1 values `[cD, cL, dp]` (John and Matthies
/// 2001; Nabh 1998), inside the intervals of [`DFG_2D1`].
pub const DFG_2D1_HIGH_ACCURACY: [f64; 3] = [5.57953, 0.010618, 0.11752];

/// The floors of the examples (the flow-step issue): 2D-1 drag and 2D-2
/// Strouhal number within 5 % of the published interval.
const FLOOR: f64 = 0.05;
const FLOOR_SOURCE: &str = "Schaefer-Turek 1996 Table 4 interval; 5 % (the flow-step issue)";

/// The DFG channel on a grid of `cpd` cells across the diameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DfgChannel {
    /// Cells across the cylinder's diameter.
    pub cpd: usize,
    /// The channel's height (0.41 in the benchmark; 0.40 centres the cylinder).
    pub height: f64,
    /// The Courant number of a step at the inflow's peak.
    pub courant: f64,
    /// The half-width of the control volume of [`DfgChannel::control_box`]
    /// (0.1, one diameter).
    pub cv_half_width: f64,
    /// The body as an immersed circle ([`crate::SceneBuilder::immersed`])
    /// instead of the staircase (default false). [`DfgChannel::force`] stays
    /// the staircase's surface formula; [`DfgChannel::body_force`] is the
    /// force of either body.
    pub immersed: bool,
    /// What lies inside the immersed circle (default [`Interior::Solid`]).
    pub interior: Interior,
    /// How the immersed circle's faces are forced (default
    /// [`ForcingScheme::Direct`]).
    pub scheme: ForcingScheme,
}

impl DfgChannel {
    /// The DFG channel at `cpd` cells per diameter, Courant number 0.4.
    ///
    /// # Errors
    /// [`FlowError::InvalidParameter`] for fewer than 4 cells per diameter.
    pub fn new(cpd: usize) -> Result<Self> {
        if cpd < 4 {
            return Err(FlowError::parameter(
                "DFG channel",
                "cpd",
                format!("at least 4 cells across the diameter, got {cpd}"),
            ));
        }
        Ok(DfgChannel {
            cpd,
            height: DFG_HEIGHT,
            courant: 0.4,
            cv_half_width: DFG_DIAMETER,
            immersed: false,
            interior: Interior::Solid,
            scheme: ForcingScheme::Direct,
        })
    }

    /// The scene with parabolic inflow of peak `um`.
    ///
    /// # Errors
    /// [`FlowError::InvalidParameter`] for a height, Courant number or `um`
    /// that is not positive; those of [`crate::SceneBuilder::build`].
    pub fn scene(&self, um: f64) -> Result<Scene> {
        positive("DFG channel", "height", self.height)?;
        positive("DFG channel", "courant", self.courant)?;
        positive("DFG channel", "um", um)?;
        let h = DFG_DIAMETER / self.cpd as f64;
        let nx = (DFG_LENGTH / h).round() as usize;
        let ny = (self.height / h).round() as usize;
        let dt = self.courant * h / um;
        let (dx, dy) = (DFG_LENGTH / nx as f64, self.height / ny as f64);
        let explicit = DFG_NU * dt * (1.0 / (dx * dx) + 1.0 / (dy * dy)) <= 0.45;
        let circle = Circle::new(DFG_CENTRE, DFG_DIAMETER / 2.0)?;
        let builder = Scene::builder(nx, ny, [DFG_LENGTH, self.height]);
        if self.immersed {
            builder
                .immersed(circle)
                .immersed_interior(self.interior)
                .immersed_scheme(self.scheme)
        } else {
            builder.obstacle(Obstacle::cylinder(circle.center, circle.radius))
        }
        .sides(Sides::channel())
        .parabolic_inflow(um)
        .viscosity(DFG_NU)
        .dt(dt)
        .advection(Advection::MacCormack { limiter: true })
        .viscosity_mode(if explicit {
            ViscosityMode::Explicit
        } else {
            ViscosityMode::Implicit
        })
        .substepping(true)
        .build()
    }

    /// The start: the inflow profile carried through the whole channel (the
    /// obstacle's faces are set to zero by the first step).
    pub fn start(scene: &Scene) -> FlowState<f64> {
        let profile = scene.params::<f64>().inflow;
        let g = scene.grid();
        let ux = Array2::from_shape_fn(g.shape_x(), |(_, b)| profile[b]);
        FlowState::from_velocity(scene, ux, Array2::zeros(g.shape_y()))
    }

    /// `p(0.15, 0.2) − p(0.25, 0.2)`: along the two rows of cells around
    /// y = 0.2, the last fluid cells before the body (the first after it)
    /// extrapolated linearly to the front (back) point, averaged over the rows.
    pub fn pressure_difference(scene: &Scene, s: &FlowState<f64>) -> f64 {
        let g = scene.grid();
        // the circle's cells, solid or (an immersed interior) forced
        let solid = &Obstacle::cylinder(DFG_CENTRE, DFG_DIAMETER / 2.0)
            .rasterise(g)
            .unwrap_or_else(|_| scene.solid().clone());
        let yc = DFG_CENTRE[1] / g.dy - 0.5;
        let rows = [yc.floor() as usize, yc.ceil() as usize];
        let weight = [1.0 - (yc - yc.floor()), yc - yc.floor()];
        let xc = |i: usize| (i as f64 + 0.5) * g.dx;
        let (front, back) = (
            DFG_CENTRE[0] - DFG_DIAMETER / 2.0,
            DFG_CENTRE[0] + DFG_DIAMETER / 2.0,
        );
        let p = |i: usize, j: usize| s.pressure[[i.min(g.nx - 1), j]];
        let mut dp = 0.0;
        for (&j, &w) in rows.iter().zip(&weight) {
            let w = if rows[0] == rows[1] { 0.5 } else { w };
            let first_solid = (0..g.nx).find(|&i| solid[[i, j]]).unwrap_or(g.nx - 1);
            let last_solid = (0..g.nx).rev().find(|&i| solid[[i, j]]).unwrap_or(0);
            let (f1, f0) = (first_solid.saturating_sub(1), first_solid.saturating_sub(2));
            let p_front = p(f1, j) + (front - xc(f1)) * (p(f1, j) - p(f0, j)) / g.dx;
            let (b1, b0) = (last_solid + 1, last_solid + 2);
            let p_back = p(b1, j) + (back - xc(b1)) * (p(b1, j) - p(b0, j)) / g.dx;
            dp += w * (p_front - p_back);
        }
        dp
    }
}

/// Test case 2D-1 on a [`DfgChannel`]: run to steady state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dfg2d1 {
    /// The channel.
    pub channel: DfgChannel,
    /// Steady when no face changes by more than this per unit time.
    pub tol: f64,
    /// The time to stop at, steady or not.
    pub max_time: f64,
}

/// A 2D-1 run against [`DFG_2D1`].
#[derive(Debug, Clone)]
pub struct SteadyCylinder {
    /// `[cD, cL, dp]` at the last state, the forces by the body's own method
    /// ([`DfgChannel::coefficients`]: the surface integral on the staircase,
    /// the forcing's momentum exchange on an immersed body).
    pub values: [f64; 3],
    /// How far each lies outside its interval, relative (0 inside).
    pub errors: [f64; 3],
    /// `[cD, cL]` at the last state by the momentum balance over
    /// [`SteadyCylinder::cv_box`] ([`DfgChannel::control_volume_coefficients`],
    /// the time term from one more step): the second force method.
    pub control_volume: [f64; 2],
    /// How far each of [`SteadyCylinder::control_volume`] lies outside its
    /// interval, relative.
    pub control_volume_errors: [f64; 2],
    /// The control volume, [`DfgChannel::control_box`] (one box, not a mean
    /// over several).
    pub cv_box: FaceBox,
    /// The 2D-1 floors: cD within 5 % of the interval; on an immersed body
    /// also the two force methods within 1 % of the drag of each other
    /// (issue 42).
    pub floors: Vec<FloorCheck>,
    /// `[t, cD, cL]` after each window of the run (every 100 steps), the
    /// force as in [`DfgChannel::coefficients`]: how the forces settle.
    pub history: Vec<[f64; 3]>,
    /// The scene.
    pub scene: Scene,
    /// The run.
    pub run: SteadyRun,
}

impl Dfg2d1 {
    /// 2D-1 at `cpd` cells per diameter, to 1e-4 per unit time or t = 40.
    ///
    /// # Errors
    /// As [`DfgChannel::new`].
    pub fn new(cpd: usize) -> Result<Self> {
        Ok(Dfg2d1 {
            channel: DfgChannel::new(cpd)?,
            tol: 1e-4,
            max_time: 40.0,
        })
    }

    /// Runs the case, recording `[t, cD, cL]` and calling
    /// `observe(steps, state, rate)` every 100 steps.
    ///
    /// # Errors
    /// Those of [`DfgChannel::scene`], [`run_to_steady`] and `observe`; those
    /// of [`control_volume_force`] for a control box that cuts the body or
    /// leaves the channel (checked before the run).
    pub fn run(&self, observe: &mut Observer<'_>) -> Result<SteadyCylinder> {
        let scene = self.channel.scene(DFG_2D1.um)?;
        let cv_box = self.channel.control_box(&scene);
        let start = DfgChannel::start(&scene);
        control_volume_force(&scene, cv_box, &start, None, DFG_NU)?;
        let stop = SteadyStop {
            tol: self.tol,
            max_time: self.max_time,
            window: 100,
        };
        let mut history = Vec::new();
        let mut record = |steps: usize, s: &FlowState<f64>, rate: f64| {
            let [cd, cl] = DfgChannel::coefficients(&scene, s, DFG_2D1.ubar)?;
            history.push([steps as f64 * scene.dt(), cd, cl]);
            observe(steps, s, rate)
        };
        let run = run_to_steady(&scene, start, stop, &mut record)?;
        let [cd, cl] = DfgChannel::coefficients(&scene, &run.state, DFG_2D1.ubar)?;
        let dp = DfgChannel::pressure_difference(&scene, &run.state);
        let errors = [
            DFG_2D1.cd.outside(cd),
            DFG_2D1.cl.outside(cl),
            DFG_2D1.dp.outside(dp),
        ];
        let next = scene.forward(&run.state, &scene.params())?.0;
        let cv = DfgChannel::control_volume_coefficients(
            &scene,
            cv_box,
            &run.state,
            Some(&next),
            DFG_2D1.ubar,
        )?;
        Ok(SteadyCylinder {
            values: [cd, cl, dp],
            errors,
            control_volume: cv,
            control_volume_errors: [DFG_2D1.cd.outside(cv[0]), DFG_2D1.cl.outside(cv[1])],
            cv_box,
            floors: steady_floors(&scene, errors[0], [cd, cl], cv),
            history,
            scene,
            run,
        })
    }
}

/// The 2D-1 floors: the drag within [`FLOOR`] of the interval; on an
/// immersed body, the body's force `f` and the control volume's `cv` (both
/// `[cD, cL]`) within 1 % of the drag of each other in each component.
fn steady_floors(scene: &Scene, cd_error: f64, f: [f64; 2], cv: [f64; 2]) -> Vec<FloorCheck> {
    let mut floors = vec![FloorCheck::at_most(
        "2D-1 cD distance outside the interval",
        cd_error,
        FLOOR,
        FLOOR_SOURCE,
    )];
    if scene.immersed().is_some() {
        let apart = (0..2)
            .map(|d| (f[d] - cv[d]).abs() / cv[0].abs())
            .fold(0.0, f64::max);
        floors.push(FloorCheck::at_most(
            "2D-1 forcing exchange vs control volume, |difference| / cD",
            apart,
            0.01,
            "issue 42: the two force methods agree to 1 % of the drag",
        ));
    }
    floors
}

impl SteadyCylinder {
    /// Whether every floor is met.
    pub fn floors_met(&self) -> bool {
        super::all_met(&self.floors)
    }
}

/// Test case 2D-2 on a [`DfgChannel`]: run to `t_end`, analyse the last
/// `window` time units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dfg2d2 {
    /// The channel.
    pub channel: DfgChannel,
    /// The end time.
    pub t_end: f64,
    /// The analysed time at the end.
    pub window: f64,
}

/// A 2D-2 run against [`DFG_2D2`].
#[derive(Debug, Clone)]
pub struct PeriodicCylinder {
    /// The Strouhal number `D / (period Ubar)`, NaN with fewer than three
    /// up-crossings of the mean lift in the window.
    pub strouhal: f64,
    /// The largest cD in the window.
    pub cd_max: f64,
    /// The largest cL in the window.
    pub cl_max: f64,
    /// The smallest cL in the window.
    pub cl_min: f64,
    /// The mean cL in the window.
    pub cl_mean: f64,
    /// The lengths of the lift's periods in the window.
    pub periods: Vec<f64>,
    /// Whether the last two periods agree to 1 %.
    pub periodic: bool,
    /// `[t, cD, cL]` at every step of the window, the surface force.
    pub history: Vec<[f64; 3]>,
    /// How far St, max cD and max cL lie outside their intervals, relative.
    pub errors: [f64; 3],
    /// The largest cD in the window by the momentum balance over
    /// [`PeriodicCylinder::cv_box`].
    pub cd_max_cv: f64,
    /// The largest cL in the window by the momentum balance.
    pub cl_max_cv: f64,
    /// How far [`PeriodicCylinder::cd_max_cv`] and
    /// [`PeriodicCylinder::cl_max_cv`] lie outside their intervals, relative.
    pub cv_errors: [f64; 2],
    /// `[t, cD, cL]` by the momentum balance at each half step of the window,
    /// `t = (k − ½) dt` between steps `k − 1` and `k`: the mean of the two
    /// states' surface terms of [`control_volume_force`] and the time term
    /// `−(M_k − M_{k−1}) / dt` of the momentum `M` inside the box (second
    /// order in time at the half step).
    pub cv_history: Vec<[f64; 3]>,
    /// The control volume, [`DfgChannel::control_box`].
    pub cv_box: FaceBox,
    /// The 2D-2 floor: St within 5 % of the interval.
    pub floors: Vec<FloorCheck>,
    /// Steps and substeps taken.
    pub steps: [usize; 2],
    /// The scene.
    pub scene: Scene,
    /// The last state.
    pub state: FlowState<f64>,
}

impl Dfg2d2 {
    /// 2D-2 at `cpd` cells per diameter to t = 12, window 4.
    ///
    /// # Errors
    /// As [`DfgChannel::new`].
    pub fn new(cpd: usize) -> Result<Self> {
        Ok(Dfg2d2 {
            channel: DfgChannel::new(cpd)?,
            t_end: 12.0,
            window: 4.0,
        })
    }

    /// Runs the case.
    ///
    /// # Errors
    /// [`FlowError::InvalidParameter`] unless `0 < window < t_end`; those of
    /// [`DfgChannel::scene`] and [`Scene::forward`]; those of
    /// [`control_volume_force`] for a control box that cuts the body or
    /// leaves the channel (checked before the run).
    pub fn run(&self) -> Result<PeriodicCylinder> {
        positive("DFG 2D-2", "window", self.window)?;
        if self.t_end.is_nan() || self.window >= self.t_end {
            return Err(FlowError::parameter(
                "DFG 2D-2",
                "window",
                format!("must be shorter than t_end = {}", self.t_end),
            ));
        }
        let scene = self.channel.scene(DFG_2D2.um)?;
        let (params, dt) = (scene.params(), scene.dt());
        let mut s = DfgChannel::start(&scene);
        let cv_box = self.channel.control_box(&scene);
        // the surface terms and the momentum of a state in the control volume
        let terms = |s: &FlowState<f64>| -> Result<[[f64; 2]; 2]> {
            let f = control_volume_force(&scene, cv_box, s, None, DFG_NU)?;
            Ok([f.total(), cv_box.momentum(&scene, s)?])
        };
        let start_terms = terms(&s)?;
        let steps = (self.t_end / dt).round() as usize;
        let record_from = ((self.t_end - self.window) / dt).round() as usize;
        let c = 2.0 / (DFG_2D2.ubar * DFG_2D2.ubar * DFG_DIAMETER);
        let mut previous = (record_from <= 1).then_some(start_terms);
        let (mut history, mut cv_history, mut substeps) = (Vec::new(), Vec::new(), 0);
        for k in 1..=steps {
            let (next, info) = scene.forward(&s, &params)?;
            substeps += info.substeps;
            // an immersed body's force is that of the step just taken
            let exchange = match scene.immersed() {
                Some(_) if k >= record_from => Some(DfgChannel::exchange_force(&scene, &s, &info)?),
                _ => None,
            };
            s = next;
            if k >= record_from {
                let f = match exchange {
                    Some(f) => f,
                    None => DfgChannel::body_force(&scene, &s)?,
                };
                let [cd, cl] = super::dfg_forces::coefficients(f, DFG_2D2.ubar);
                history.push([k as f64 * dt, cd, cl]);
            }
            if k + 1 >= record_from {
                let [flux, momentum] = terms(&s)?;
                if let Some([flux0, momentum0]) = previous.filter(|_| k >= record_from) {
                    let f = [0, 1].map(|d| {
                        c * (0.5 * (flux0[d] + flux[d]) - (momentum[d] - momentum0[d]) / dt)
                    });
                    cv_history.push([(k as f64 - 0.5) * dt, f[0], f[1]]);
                }
                previous = Some([flux, momentum]);
            }
        }
        let cv = ControlVolumeRecord {
            cv_box,
            history: cv_history,
        };
        Ok(analyse(history, cv, [steps, substeps], scene, s))
    }
}

/// The momentum-balance forces of a 2D-2 window.
struct ControlVolumeRecord {
    cv_box: FaceBox,
    history: Vec<[f64; 3]>,
}

/// The Strouhal number and the extrema of a 2D-2 history.
fn analyse(
    history: Vec<[f64; 3]>,
    cv: ControlVolumeRecord,
    steps: [usize; 2],
    scene: Scene,
    state: FlowState<f64>,
) -> PeriodicCylinder {
    let column = |c: usize| history.iter().map(move |h| h[c]);
    let cd_max = column(1).fold(f64::NEG_INFINITY, f64::max);
    let cl_max = column(2).fold(f64::NEG_INFINITY, f64::max);
    let cl_min = column(2).fold(f64::INFINITY, f64::min);
    let times: Vec<f64> = column(0).collect();
    let lift: Vec<f64> = column(2).collect();
    let shedding = Shedding::of(&times, &lift);
    // At least three crossings (two periods) for a Strouhal number.
    let strouhal = match shedding.crossings.len() {
        0..=2 => f64::NAN,
        _ => shedding
            .strouhal(DFG_DIAMETER, DFG_2D2.ubar)
            .unwrap_or(f64::NAN),
    };
    let periodic = shedding.settled(0.01);
    let Shedding { mean, periods, .. } = shedding;
    let errors = [
        DFG_2D2.strouhal.outside(strouhal),
        DFG_2D2.cd_max.outside(cd_max),
        DFG_2D2.cl_max.outside(cl_max),
    ];
    let cv_max = |c: usize| {
        cv.history
            .iter()
            .map(|h| h[c])
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let (cd_max_cv, cl_max_cv) = (cv_max(1), cv_max(2));
    PeriodicCylinder {
        strouhal,
        cd_max,
        cl_max,
        cl_min,
        cl_mean: mean,
        periods,
        periodic,
        history,
        errors,
        cd_max_cv,
        cl_max_cv,
        cv_errors: [
            DFG_2D2.cd_max.outside(cd_max_cv),
            DFG_2D2.cl_max.outside(cl_max_cv),
        ],
        cv_history: cv.history,
        cv_box: cv.cv_box,
        floors: vec![FloorCheck::at_most(
            "2D-2 St distance outside the interval",
            errors[0],
            FLOOR,
            FLOOR_SOURCE,
        )],
        steps,
        scene,
        state,
    }
}

impl PeriodicCylinder {
    /// Whether every floor is met.
    pub fn floors_met(&self) -> bool {
        super::all_met(&self.floors)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reference_cases_match_their_definitions() {
        for (um, ubar, re) in [
            (DFG_2D1.um, DFG_2D1.ubar, 20.0),
            (DFG_2D2.um, DFG_2D2.ubar, 100.0),
        ] {
            // Ubar = 2 Um / 3 (the mean of the parabola), Re = Ubar D / ν
            assert!((ubar - 2.0 * um / 3.0).abs() < 1e-12);
            assert!((ubar * DFG_DIAMETER / DFG_NU - re).abs() < 1e-9);
        }
        let [cd, cl, dp] = DFG_2D1_HIGH_ACCURACY;
        assert_eq!(
            [
                DFG_2D1.cd.outside(cd),
                DFG_2D1.cl.outside(cl),
                DFG_2D1.dp.outside(dp)
            ],
            [0.0; 3]
        );
    }

    #[test]
    fn bad_settings_are_typed_errors() {
        assert!(DfgChannel::new(3).is_err());
        let mut case = Dfg2d2::new(4).unwrap();
        case.window = 20.0;
        assert!(matches!(
            case.run(),
            Err(FlowError::InvalidParameter { .. })
        ));
        let mut channel = DfgChannel::new(4).unwrap();
        channel.courant = f64::NAN;
        assert!(channel.scene(1.0).is_err());
    }

    #[test]
    fn a_sine_lift_gives_its_frequency() {
        // cL = sin(2π t / 0.3): period 0.3, St = D / (0.3 Ubar)
        let history: Vec<[f64; 3]> = (0..3000)
            .map(|k| {
                let t = k as f64 * 1e-3;
                [t, 3.0, (2.0 * std::f64::consts::PI * t / 0.3).sin()]
            })
            .collect();
        let channel = DfgChannel::new(4).unwrap();
        let scene = channel.scene(1.5).unwrap();
        let state = DfgChannel::start(&scene);
        let cv = ControlVolumeRecord {
            cv_box: channel.control_box(&scene),
            history: history.clone(),
        };
        let r = analyse(history, cv, [0, 0], scene, state);
        assert!(
            (r.strouhal - DFG_DIAMETER / 0.3).abs() < 1e-6,
            "{}",
            r.strouhal
        );
        assert!(r.periodic);
        assert!((r.cl_max - 1.0).abs() < 1e-4);
        assert_eq!([r.cd_max_cv, r.cl_max_cv], [r.cd_max, r.cl_max]);
    }
}
