//! The physics of `solver_in_the_loop`: a coarse advection solver on the tape
//! and a finer reference reduced to the coarse grid.
//!
//! Advection of a density `d` by a fixed, spatially varying velocity,
//! `∂d/∂t + c(x) ∂d/∂x = 0` with `c(x) = 1 + ½ sin πx`, on the periodic domain
//! [−1, 1]. Both solvers take first-order upwind steps (`upwind1` of
//! `diffphys-ops`):
//!
//! - coarse: [`COARSE`] cells, one step of `dt` = [`DT`] per step (Courant
//!   numbers 0.25 to 0.75);
//! - reference (the "source"): [`FINE`] = 8 × [`COARSE`] cells, [`SUBSTEPS`]
//!   steps of `dt / SUBSTEPS` per coarse step (the same Courant numbers),
//!   reduced to the coarse grid by averaging each block of eight cells.
//!
//! The initial densities are random square pulses. Upwind's numerical diffusion
//! is proportional to the cell size, so on the coarse grid the pulses' edges
//! smear over several cells within a few steps, while the reference keeps them
//! sharp to within about a coarse cell over the whole rollout. Nothing in the
//! physics forgets an error: the exact solution only moves the density, so a
//! smeared edge stays smeared and a misplaced one stays misplaced, and the
//! coarse error grows for as long as the rollout runs.
//!
//! The coarse step is one tape op over a batch `[batch, 1, COARSE]`
//! ([`CoarseStepOp`]); it is linear in the density, and its adjoint is the
//! field adjoint of `upwind1` (`upwind1_vjp`).

use std::sync::Arc;

use diffphys::learn::{Corrector, Simulator, State, StateVars, TrainSeed, Trajectory};
use diffphys::nn::{Activation, Bound, Layer, Padding, Params, UNet, UNetConfig};
use diffphys::ops::advection::{upwind1, upwind1_vjp, AdvectionParams, Wants};
use diffphys::prelude::*;
use diffphys::tape::Result as TapeResult;
use ndarray::{s, Array1, Array2, ArrayView1, Axis};
use rand::Rng;

pub type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// Cells of the coarse grid.
pub const COARSE: usize = 32;
/// Reference cells per coarse cell.
pub const RATIO: usize = 8;
/// Cells of the reference grid.
pub const FINE: usize = RATIO * COARSE;
/// Reference steps per coarse step.
pub const SUBSTEPS: usize = 8;
/// The coarse time step: Courant numbers `dt·c(x)/dx` from 0.25 to 0.75.
pub const DT: f64 = 1.0 / 32.0;
/// The velocity's variation, `c(x) = 1 + VARIATION·sin πx`.
pub const VARIATION: f64 = 0.5;
/// Square pulses per initial state.
pub const PULSES: usize = 2;

/// One solver: a grid, a time step and the velocity at the cell centres.
#[derive(Debug, Clone)]
pub struct Solver {
    pub grid: Grid1,
    pub dt: f64,
    velocity: Arc<Array1<f64>>,
}

impl Solver {
    pub fn new(cells: usize, dt: f64) -> Result<Self, BoxError> {
        let grid = Grid1::over(-1.0, 1.0, cells, Boundary::Periodic)?;
        let pi = std::f64::consts::PI;
        let velocity = Array1::from_iter(
            grid.centers()
                .into_iter()
                .map(|x| 1.0 + VARIATION * (pi * x).sin()),
        );
        Ok(Solver {
            grid,
            dt,
            velocity: Arc::new(velocity),
        })
    }

    /// The coarse solver.
    pub fn coarse() -> Result<Self, BoxError> {
        Solver::new(COARSE, DT)
    }

    /// The reference solver (one of its steps is a substep of a coarse step).
    pub fn fine() -> Result<Self, BoxError> {
        Solver::new(FINE, DT / SUBSTEPS as f64)
    }

    /// The velocity at the cell centres, repeated for a `[batch, 1, n]` batch.
    pub fn velocity_batch(&self, batch: usize) -> ArrayD<f64> {
        let n = self.grid.n;
        let mut out = ArrayD::zeros(vec![batch, 1, n]);
        for mut row in out.axis_iter_mut(Axis(0)) {
            row.slice_mut(s![0, ..]).assign(&*self.velocity);
        }
        out
    }

    /// One upwind step of one density.
    pub fn step(&self, d: ArrayView1<'_, f64>) -> TapeResult<Array1<f64>> {
        upwind1(
            &self.grid,
            &AdvectionParams::new(self.dt),
            d,
            self.velocity.view(),
        )
        .map_err(|e| TapeError::op("advection step", e))
    }

    /// The vector–Jacobian product of [`Solver::step`] for `g = ∂L/∂d'`.
    pub fn step_vjp(&self, g: ArrayView1<'_, f64>) -> TapeResult<Array1<f64>> {
        let zeros = Array1::zeros(self.grid.n);
        let grads = upwind1_vjp(
            &self.grid,
            &AdvectionParams::new(self.dt),
            zeros.view(),
            self.velocity.view(),
            g,
            Wants {
                field: true,
                velocity: false,
            },
        )
        .map_err(|e| TapeError::op("advection step adjoint", e))?;
        Ok(grads.field.expect("asked for"))
    }

    /// Records one step of every state of a `[batch, 1, n]` batch.
    pub fn step_tape<'t>(&self, u: Var<'t, f64>) -> TapeResult<Var<'t, f64>> {
        u.tape().apply(
            CoarseStepOp {
                solver: self.clone(),
            },
            &[u],
        )
    }
}

/// The coarse solver as the library's simulator: one upwind step of a batch.
impl Simulator for Solver {
    fn step<'t>(&self, u: &StateVars<'t>) -> TapeResult<Vec<Var<'t, f64>>> {
        Ok(vec![self.step_tape(u.only()?)?])
    }
}

/// One solver step of a `[batch, 1, n]` batch as a tape op (see the module
/// docs). Linear, so it keeps nothing for its backward.
#[derive(Debug, Clone)]
pub struct CoarseStepOp {
    solver: Solver,
}

fn rows_of(name: &str, x: &ArrayViewD<'_, f64>, n: usize) -> TapeResult<usize> {
    match *x.shape() {
        [b, 1, m] if m == n => Ok(b),
        _ => Err(TapeError::shape(name, &[x.shape()[0], 1, n], x.shape())),
    }
}

impl Op<f64> for CoarseStepOp {
    fn name(&self) -> &str {
        "advection_step"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, f64>]) -> TapeResult<Vec<ArrayD<f64>>> {
        let x = &inputs[0];
        rows_of(self.name(), x, self.solver.grid.n)?;
        let mut out = ArrayD::zeros(x.shape());
        for (row, mut dst) in x.axis_iter(Axis(0)).zip(out.axis_iter_mut(Axis(0))) {
            let u = row.slice(s![0, ..]);
            dst.slice_mut(s![0, ..]).assign(&self.solver.step(u)?);
        }
        Ok(vec![out])
    }

    fn backward(&self, args: &BackwardArgs<'_, f64>) -> TapeResult<Vec<Option<ArrayD<f64>>>> {
        let g = args.grad_out();
        let mut out = ArrayD::zeros(g.shape());
        for (grow, mut dst) in g.axis_iter(Axis(0)).zip(out.axis_iter_mut(Axis(0))) {
            let back = self.solver.step_vjp(grow.slice(s![0, ..]))?;
            dst.slice_mut(s![0, ..]).assign(&back);
        }
        Ok(vec![Some(out)])
    }
}

/// The length of `[a, b] ∩ [lo, hi]` on the periodic domain [−1, 1].
fn overlap(a: f64, b: f64, lo: f64, hi: f64) -> f64 {
    [-2.0, 0.0, 2.0]
        .iter()
        .map(|shift| ((b + shift).min(hi) - (a + shift).max(lo)).max(0.0))
        .sum()
}

/// A random density of square pulses: [`PULSES`] pulses, each with a centre
/// uniform on [−1, 1], a width uniform on [0.25, 0.6] and a height uniform on
/// [0.5, 1.5], summed; the exact cell averages on `grid`.
pub fn random_initial_state(grid: &Grid1, rng: &mut impl Rng) -> Array1<f64> {
    let pulses: Vec<(f64, f64, f64)> = (0..PULSES)
        .map(|_| {
            let centre = rng.random_range(-1.0..1.0);
            let width = rng.random_range(0.25..0.6);
            let height = rng.random_range(0.5..1.5);
            (centre - width / 2.0, centre + width / 2.0, height)
        })
        .collect();
    let h = grid.dx;
    Array1::from_iter(grid.centers().into_iter().map(|x| {
        pulses
            .iter()
            .map(|&(a, b, height)| height * overlap(a, b, x - h / 2.0, x + h / 2.0) / h)
            .sum::<f64>()
    }))
}

/// The fine state averaged over each block of [`RATIO`] cells.
pub fn reduce(fine: ArrayView1<'_, f64>) -> Array1<f64> {
    let r = RATIO;
    Array1::from_iter((0..COARSE).map(|i| fine.slice(s![i * r..(i + 1) * r]).sum() / r as f64))
}

/// The reference from a fine initial state: `steps + 1` coarse states (rows),
/// the initial one first.
pub fn reference_trajectory(
    fine: &Solver,
    u0: &Array1<f64>,
    steps: usize,
) -> Result<Array2<f64>, BoxError> {
    let mut out = Array2::zeros((steps + 1, COARSE));
    let mut u = u0.clone();
    out.row_mut(0).assign(&reduce(u.view()));
    for t in 1..=steps {
        for _ in 0..SUBSTEPS {
            u = fine.step(u.view())?;
        }
        out.row_mut(t).assign(&reduce(u.view()));
    }
    Ok(out)
}

/// `count` reference trajectories of `steps` steps from initial states drawn by
/// `rng`.
pub fn reference_set(
    count: usize,
    steps: usize,
    rng: &mut impl Rng,
) -> Result<Vec<Array2<f64>>, BoxError> {
    let fine = Solver::fine()?;
    (0..count)
        .map(|_| {
            let u0 = random_initial_state(&fine.grid, rng);
            reference_trajectory(&fine, &u0, steps)
        })
        .collect()
}

/// `count` reference trajectories of `steps` steps from initial states drawn by
/// `rng`, each state a `[1, COARSE]` array (one channel).
pub fn trajectories(
    count: usize,
    steps: usize,
    rng: &mut impl Rng,
) -> Result<Vec<Trajectory>, BoxError> {
    Ok(reference_set(count, steps, rng)?
        .into_iter()
        .map(|tr| {
            tr.rows()
                .into_iter()
                .map(|r| State::from(r.to_owned().insert_axis(Axis(0)).into_dyn()))
                .collect()
        })
        .collect())
}

/// The root mean square of `coarse step − reference` over the first step from
/// every initial state of `set`: the error one coarse step makes.
pub fn one_step_rms(solver: &Solver, set: &[Trajectory]) -> Result<f64, BoxError> {
    let mut sum = 0.0;
    for tr in set {
        let u = solver.step(tr[0].fields[0].slice(s![0, ..]))?;
        sum += (&u - &tr[1].fields[0].slice(s![0, ..]))
            .mapv(|e| e * e)
            .sum();
    }
    Ok((sum / (set.len() * COARSE) as f64).sqrt())
}
pub mod study;

/// The corrector: a U-Net on the stepped state and the velocity.
pub struct Net {
    unet: UNet,
    solver: Solver,
}

impl Corrector for Net {
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        v: &StateVars<'t>,
    ) -> diffphys::tape::Result<Vec<Var<'t, f64>>> {
        let v = v.only()?;
        let c = v.tape().constant(self.solver.velocity_batch(v.shape()[0]));
        Ok(vec![self.unet.forward(p, Var::concat(&[v, c], 1)?)?])
    }
}

pub fn network(seed: TrainSeed) -> Result<(Net, Params<f64>), BoxError> {
    let config = UNetConfig {
        dims: 1,
        c_in: 2,
        c_out: 1,
        widths: vec![16, 32],
        kernel: 5,
        padding: Padding::Periodic,
        activation: Activation::Relu,
    };
    let mut params = Params::new();
    let unet = UNet::new(&mut params, "corrector", config, &mut seed.init_rng())?;
    Ok((
        Net {
            unet,
            solver: Solver::coarse()?,
        },
        params,
    ))
}
