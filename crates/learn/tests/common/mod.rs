//! The tiny scene the strategy and study tests share: a cubic step, its
//! slightly different reference, a small periodic U-Net corrector.

#![allow(dead_code)]

use diffphys_learn::*;
use diffphys_nn::{Activation, Bound, Layer, Padding, Params, UNet, UNetConfig};
use diffphys_tape::{ArrayD, Var};
use rand::Rng;

pub const CELLS: usize = 8;

/// A nonlinear, smooth step: `u ↦ 0.9 u − 0.05 u³`.
#[derive(Clone)]
pub struct Cubic;

impl Simulator for Cubic {
    fn step<'t>(&self, u: &StateVars<'t>) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        let u = u.only()?;
        Ok(vec![u
            .mul_scalar(0.9)?
            .sub(u.powi(3)?.mul_scalar(0.05)?)?])
    }
}

/// The reference: `u ↦ 0.95 u − 0.04 u³` (the solver is slightly off).
pub fn reference_step(u: &ArrayD<f64>) -> ArrayD<f64> {
    u.mapv(|x| 0.95 * x - 0.04 * x.powi(3))
}

pub struct Net(pub UNet);

impl Corrector for Net {
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        u: &StateVars<'t>,
    ) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        Ok(vec![self.0.forward(p, u.only()?)?])
    }
}

pub fn config(c_out: usize) -> UNetConfig {
    UNetConfig {
        dims: 1,
        c_in: 1,
        c_out,
        widths: vec![2, 3],
        kernel: 3,
        padding: Padding::Periodic,
        activation: Activation::Tanh,
    }
}

/// A network whose head does not start at zero (so every gradient is non-trivial).
pub fn net(seed: u64, c_out: usize) -> (Net, Params<f64>) {
    let mut params = Params::<f64>::new();
    let unet = UNet::new(
        &mut params,
        "c",
        config(c_out),
        &mut TrainSeed(seed).init_rng(),
    )
    .unwrap();
    let mut rng = TrainSeed(seed + 100).init_rng();
    let mut perturbed = Params::new();
    for (name, v) in params.names().iter().zip(params.values()) {
        let v = v.mapv(|x| x + 0.1 * rng.random_range(-1.0f64..1.0));
        perturbed.add(name.clone(), v).unwrap();
    }
    (Net(unet), perturbed)
}

pub fn splits(seed: u64, sizes: [usize; 3], steps: usize) -> Splits<Vec<Trajectory>> {
    Splits::generate(DataSeed(seed), sizes, |_, n, rng| {
        Ok((0..n)
            .map(|_| {
                let mut u = ArrayD::from_shape_fn(vec![1, CELLS], |_| rng.random_range(-1.0..1.0));
                let mut tr = vec![State::from(u.clone())];
                for _ in 0..steps {
                    u = reference_step(&u);
                    tr.push(State::from(u.clone()));
                }
                tr
            })
            .collect())
    })
    .unwrap()
}

pub fn trainer(iterations: usize, evaluations: usize) -> Trainer {
    Trainer {
        budget: Budget {
            iterations,
            evaluations_per_iteration: evaluations,
        },
        learning_rate: 1e-2,
        schedule: LrSchedule::Exponential {
            final_fraction: 0.1,
        },
        validate_every: 10,
        validation_steps: 8,
    }
}
