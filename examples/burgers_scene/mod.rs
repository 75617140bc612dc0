//! The Burgers scene of `burgers_inverse`, shared by the examples that train
//! networks through it (`nn_control_burgers`, `nn_solver_data`).
//!
//! 1D periodic domain [−1, 1], 128 cells, dt = 1/32, ν = 0.01/(128π). Each step is
//! explicit diffusion `u + ν·dt·∇²u`, then semi-Lagrangian self-advection of the
//! diffused state. The observed state is the one after step 16 (t = 0.5).
//! Random initial states are smooth periodic sums of the first four Fourier modes.

#![allow(dead_code)] // each example uses a different part

use std::sync::Arc;

use diffphys::nn::{Activation, Padding, Params, UNet, UNetConfig};
use diffphys::ops::advection::{semi_lagrangian1, SemiLagrangian1};
use diffphys::ops::stencil::{DiffusionParams, ExplicitDiffusion1};
use diffphys::ops::tape_ops::LinearOp;
use diffphys::prelude::*;
use ndarray::{Array1, Ix1};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

pub type BoxError = Box<dyn std::error::Error>;

/// Cells of the grid.
pub const N: usize = 128;
/// Steps of the full simulation (the time step is 1/STEPS).
pub const STEPS: usize = 32;
/// The step whose state is observed (t = 0.5).
pub const OBSERVED_STEP: usize = 16;
/// Fourier modes of a random initial state.
pub const MODES: usize = 4;
/// Learning rate of per-instance gradient descent (as in `burgers_inverse`).
pub const DESCENT_RATE: f64 = 5.0;

/// The simulation: grid, time step and diffusion operator.
pub struct Burgers {
    pub grid: Grid1,
    pub dt: f64,
    diffusion: Arc<ExplicitDiffusion1>,
}

impl Burgers {
    pub fn new() -> Result<Self, BoxError> {
        let grid = Grid1::over(-1.0, 1.0, N, Boundary::Periodic)?;
        let dt = 1.0 / STEPS as f64;
        let nu = 0.01 / (N as f64 * std::f64::consts::PI);
        let diffusion = ExplicitDiffusion1::new(grid, DiffusionParams::new(nu, dt))?;
        Ok(Burgers {
            grid,
            dt,
            diffusion: Arc::new(diffusion),
        })
    }

    /// One step on the tape: diffuse, then advect the diffused state by itself.
    pub fn step<'t>(&self, u: Var<'t, f64>) -> Result<Var<'t, f64>, BoxError> {
        let tape = u.tape();
        let diffused = tape.apply(LinearOp::new(Arc::clone(&self.diffusion)), &[u])?;
        let advect = SemiLagrangian1::new(self.grid, self.dt);
        Ok(tape.apply(advect, &[diffused, diffused])?)
    }

    /// The observed state `P(u₀)` (16 steps) of one `[N]` state, on the tape.
    pub fn observe<'t>(&self, u0: Var<'t, f64>) -> Result<Var<'t, f64>, BoxError> {
        let mut u = u0;
        for _ in 0..OBSERVED_STEP {
            u = self.step(u)?;
        }
        Ok(u)
    }

    /// `P` applied to every sample of a `[batch, 1, N]` batch, on the tape: each
    /// sample is sliced out, stepped through the solver and stacked back.
    pub fn observe_batch<'t>(&self, u0: Var<'t, f64>) -> Result<Var<'t, f64>, BoxError> {
        let batch = u0.shape()[0];
        let observed = (0..batch)
            .map(|b| {
                let u = u0.slice(0, b, b + 1)?.reshape(&[N])?;
                Ok(self.observe(u)?.reshape(&[1, 1, N])?)
            })
            .collect::<Result<Vec<_>, BoxError>>()?;
        Ok(Var::concat(&observed, 0)?)
    }

    /// `P(u₀)` without a tape.
    pub fn observe_plain(&self, u0: &Array1<f64>) -> Result<Array1<f64>, BoxError> {
        let mut u = u0.clone();
        for _ in 0..OBSERVED_STEP {
            let diffused = self
                .diffusion
                .apply(u.view().into_dyn())?
                .into_dimensionality::<Ix1>()?;
            u = semi_lagrangian1(&self.grid, self.dt, diffused.view(), diffused.view())?;
        }
        Ok(u)
    }

    /// The physics loss `mean((P(u₀) − obs)²)` and its gradient with respect to `u₀`.
    pub fn loss_and_gradient(
        &self,
        u0: &Array1<f64>,
        obs: &Array1<f64>,
    ) -> Result<(f64, Array1<f64>), BoxError> {
        let tape = Tape::<f64>::new();
        let x = tape.var(u0.clone().into_dyn());
        let loss = self
            .observe(x)?
            .sub(tape.constant(obs.clone().into_dyn()))?
            .powi(2)?
            .mean()?;
        let mut grads = tape.backward(loss, &[x])?;
        let g = grads.take(x).ok_or("no gradient for the initial state")?;
        Ok((loss.item()?, g.into_dimensionality::<Ix1>()?))
    }

    /// `iterations` steps of plain gradient descent (rate [`DESCENT_RATE`]) on the
    /// physics loss from `u0`; returns the final state.
    pub fn descend(
        &self,
        u0: &Array1<f64>,
        obs: &Array1<f64>,
        iterations: usize,
    ) -> Result<Array1<f64>, BoxError> {
        let mut u = u0.clone();
        for _ in 0..iterations {
            let (_, g) = self.loss_and_gradient(&u, obs)?;
            u.scaled_add(-DESCENT_RATE, &g);
        }
        Ok(u)
    }
}

/// A random smooth periodic initial state
/// `u₀(x) = Σ_{k=1..4} (a_k cos kπx + b_k sin kπx) / k`, `a_k, b_k` uniform on [−1, 1].
pub fn random_initial_state(grid: &Grid1, rng: &mut impl Rng) -> Array1<f64> {
    let coefficients: Vec<(f64, f64)> = (0..MODES)
        .map(|_| (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)))
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

/// Channels per level of the network, finest first.
pub const WIDTHS: [usize; 4] = [16, 32, 32, 32];

/// The network of both scenes, its parameters drawn from `seed`: a 1D U-Net,
/// periodic padding, kernel 5, ReLU, widths [`WIDTHS`], one channel in and out.
pub fn network(seed: u64) -> Result<(Params<f64>, UNet), BoxError> {
    let config = UNetConfig {
        dims: 1,
        c_in: 1,
        c_out: 1,
        widths: WIDTHS.to_vec(),
        kernel: 5,
        padding: Padding::Periodic,
        activation: Activation::Relu,
    };
    let mut params = Params::new();
    let net = UNet::new(
        &mut params,
        "unet",
        config,
        &mut StdRng::seed_from_u64(seed),
    )?;
    Ok((params, net))
}

/// Stacks `[N]` states into a `[batch, 1, N]` array.
pub fn batch_of(states: &[&Array1<f64>]) -> ArrayD<f64> {
    let mut out = ArrayD::zeros(vec![states.len(), 1, N]);
    for (b, s) in states.iter().enumerate() {
        out.slice_mut(ndarray::s![b, 0, ..]).assign(s);
    }
    out
}

/// Sample `b` of a `[batch, 1, N]` array.
pub fn sample_of(batch: &ArrayD<f64>, b: usize) -> Array1<f64> {
    batch.slice(ndarray::s![b, 0, ..]).to_owned()
}

/// The mean squared difference of two arrays.
pub fn mse(a: &Array1<f64>, b: &Array1<f64>) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64
}

/// `(step, value)` pairs as a chart series.
pub fn curve(label: &str, points: &[(usize, f64)]) -> diffphys::report::chart::Series {
    diffphys::report::chart::Series::new(
        label,
        points.iter().map(|&(s, v)| (s as f64, v)).collect(),
    )
}
