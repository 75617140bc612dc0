//! The physics of `solver_in_the_loop`: a coarse Burgers solver on the tape and a
//! finer reference reduced to the coarse grid.
//!
//! Viscous Burgers `∂u/∂t + u ∂u/∂x = ν ∂²u/∂x²` on the periodic domain [−1, 1],
//! ν = [`NU`]. One step of either solver is explicit diffusion `u + ν·dt·∇²u`, then
//! semi-Lagrangian self-advection of the diffused state (linear interpolation),
//! the scheme of `burgers_inverse`:
//!
//! - coarse: [`COARSE`] cells, one step of `dt` = [`DT`] per step;
//! - reference (the "source"): [`FINE`] = 4 × [`COARSE`] cells, [`SUBSTEPS`] steps
//!   of `dt / SUBSTEPS` per coarse step, reduced to the coarse grid by averaging
//!   each block of four cells.
//!
//! On the coarse grid the fronts that Burgers steepens span only a few cells,
//! a coarse step moves them by two to three cells, and linear semi-Lagrangian
//! interpolation smears them, so the coarse solution lags the reference more
//! with every step. The large coarse step makes that error dynamical: where the
//! front ends up depends on the state, so an error left by one step changes the
//! next steps (rather than being damped by viscosity alone).
//!
//! The coarse step is one tape op over a batch `[batch, 1, COARSE]`
//! ([`CoarseStepOp`]); its adjoint is the adjoint of the advection
//! (`semi_lagrangian_1d_vjp`, field and velocity gradients summed, since the
//! diffused state is both) followed by the transposed diffusion (symmetric).

use std::sync::Arc;

use diffphys::ops::advection::{semi_lagrangian_1d, semi_lagrangian_1d_vjp, Wants};
use diffphys::ops::stencil::{DiffusionParams, ExplicitDiffusion1};
use diffphys::tape::Result as TapeResult;
use diffphys::{
    ArrayD, ArrayViewD, BackwardArgs, Boundary, Grid1, LinearOperator, Op, TapeError, Var,
};
use ndarray::{s, Array1, Array2, ArrayView1, Axis, Ix1};
use rand::Rng;

pub type BoxError = Box<dyn std::error::Error>;

/// Cells of the coarse grid.
pub const COARSE: usize = 32;
/// Cells of the reference grid.
pub const FINE: usize = 4 * COARSE;
/// Reference steps per coarse step.
pub const SUBSTEPS: usize = 8;
/// The coarse time step (a reference step is `DT / SUBSTEPS` = 1/128).
pub const DT: f64 = 1.0 / 16.0;
/// Viscosity.
pub const NU: f64 = 0.01;
/// The bound of the Fourier coefficients of a random initial state: with
/// velocities of 2–3, fronts form within the first five coarse steps and a coarse
/// step moves them by two to three cells.
pub const AMPLITUDE: f64 = 2.0;
/// Fourier modes of a random initial state.
pub const MODES: usize = 4;

/// One solver: a grid, a time step and its diffusion operator.
#[derive(Debug, Clone)]
pub struct Solver {
    pub grid: Grid1,
    pub dt: f64,
    diffusion: Arc<ExplicitDiffusion1>,
}

impl Solver {
    pub fn new(cells: usize, dt: f64) -> Result<Self, BoxError> {
        let grid = Grid1::over(-1.0, 1.0, cells, Boundary::Periodic)?;
        let diffusion = ExplicitDiffusion1::new(grid, DiffusionParams::new(NU, dt))?;
        Ok(Solver {
            grid,
            dt,
            diffusion: Arc::new(diffusion),
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

    fn diffuse(&self, u: ArrayView1<'_, f64>) -> TapeResult<Array1<f64>> {
        let d = self
            .diffusion
            .apply(u.into_dyn())
            .map_err(|e| TapeError::op("burgers step (diffusion)", e))?;
        Ok(d.into_dimensionality::<Ix1>().expect("1-D in, 1-D out"))
    }

    /// One step of one state: diffuse, then advect the diffused state by itself.
    pub fn step(&self, u: ArrayView1<'_, f64>) -> TapeResult<Array1<f64>> {
        let d = self.diffuse(u)?;
        semi_lagrangian_1d(&self.grid, self.dt, d.view(), d.view())
            .map_err(|e| TapeError::op("burgers step (advection)", e))
    }

    /// The vector–Jacobian product of [`Solver::step`] at `u` for `g = ∂L/∂u'`:
    /// `Dᵀ (A_dᵀ g + A_uᵀ g)` with `D` the diffusion and `A` the advection.
    pub fn step_vjp(
        &self,
        u: ArrayView1<'_, f64>,
        g: ArrayView1<'_, f64>,
    ) -> TapeResult<Array1<f64>> {
        let d = self.diffuse(u)?;
        let grads = semi_lagrangian_1d_vjp(&self.grid, self.dt, d.view(), d.view(), g, Wants::BOTH)
            .map_err(|e| TapeError::op("burgers step adjoint (advection)", e))?;
        let both = grads.field.expect("asked for") + grads.velocity.expect("asked for");
        let back = self
            .diffusion
            .apply_transpose(both.view().into_dyn())
            .map_err(|e| TapeError::op("burgers step adjoint (diffusion)", e))?;
        Ok(back.into_dimensionality::<Ix1>().expect("1-D in, 1-D out"))
    }

    /// Records one step of every state of a `[batch, 1, n]` batch.
    pub fn step_tape<'t>(&self, u: Var<'t, f64>) -> TapeResult<Var<'t, f64>> {
        u.apply1(
            CoarseStepOp {
                solver: self.clone(),
            },
            &[],
        )
    }
}

/// One solver step of a `[batch, 1, n]` batch as a tape op (see the module docs).
/// Keeps only its input; the backward recomputes the diffused state.
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
        "burgers_step"
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
        let x = args.input(0);
        let g = args.grad_out();
        let mut out = ArrayD::zeros(x.shape());
        for ((row, grow), mut dst) in x
            .axis_iter(Axis(0))
            .zip(g.axis_iter(Axis(0)))
            .zip(out.axis_iter_mut(Axis(0)))
        {
            let back = self
                .solver
                .step_vjp(row.slice(s![0, ..]), grow.slice(s![0, ..]))?;
            dst.slice_mut(s![0, ..]).assign(&back);
        }
        Ok(vec![Some(out)])
    }
}

/// A random smooth periodic state
/// `u₀(x) = Σ_{k=1..4} (a_k cos kπx + b_k sin kπx) / k`, `a_k, b_k` uniform on
/// [−A, A] with A = [`AMPLITUDE`], sampled at the cell centres of `grid`.
pub fn random_initial_state(grid: &Grid1, rng: &mut impl Rng) -> Array1<f64> {
    let a = AMPLITUDE;
    let coefficients: Vec<(f64, f64)> = (0..MODES)
        .map(|_| (rng.random_range(-a..a), rng.random_range(-a..a)))
        .collect();
    let pi = std::f64::consts::PI;
    Array1::from_iter(grid.centers().into_iter().map(|x| {
        coefficients
            .iter()
            .enumerate()
            .map(|(i, (a, b))| {
                let k = (i + 1) as f64;
                (a * (k * pi * x).cos() + b * (k * pi * x).sin()) / k
            })
            .sum::<f64>()
    }))
}

/// The fine state averaged over each block of `FINE / COARSE` cells.
pub fn reduce(fine: ArrayView1<'_, f64>) -> Array1<f64> {
    let r = FINE / COARSE;
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

/// Rows of coarse states stacked as a `[batch, 1, COARSE]` array.
pub fn batch_of(states: &[ArrayView1<'_, f64>]) -> ArrayD<f64> {
    let mut out = ArrayD::zeros(vec![states.len(), 1, COARSE]);
    for (b, u) in states.iter().enumerate() {
        out.slice_mut(s![b, 0, ..]).assign(u);
    }
    out
}

/// The mean over the batch of `‖a_b − r_b‖ / ‖r_b‖` for `[batch, 1, n]` arrays.
pub fn relative_error(a: &ArrayD<f64>, r: &ArrayD<f64>) -> f64 {
    let batch = a.shape()[0];
    (0..batch)
        .map(|b| {
            let (x, y) = (a.slice(s![b, 0, ..]), r.slice(s![b, 0, ..]));
            let diff = x
                .iter()
                .zip(y.iter())
                .map(|(p, q)| (p - q).powi(2))
                .sum::<f64>();
            (diff / y.iter().map(|q| q * q).sum::<f64>()).sqrt()
        })
        .sum::<f64>()
        / batch as f64
}
