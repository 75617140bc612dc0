//! The step's kernels take their outputs and scratch from the current buffer
//! pool, whose buffers come back with stale contents. A pool seeded with
//! NaN-filled buffers of every length the step uses, and the same pool again
//! after a first run, must give the bits of a run without one: no kernel may
//! read what it did not write. Scenes of at least
//! [`diffphys_tape::pool::MIN_POOLED_LEN`] entries per field, so the pool is
//! used.

mod common;

use diffphys_flow::{
    Advection, FlowState, FlowVars, Obstacle, ParamVars, PressureSolver, Scene, Sides,
    ViscosityMode,
};
use diffphys_tape::pool::{self, BufferPool};
use diffphys_tape::{test_array, Schedule, Tape};
use ndarray::Array2;

fn scenes() -> Vec<(&'static str, Scene)> {
    let periodic = Scene::builder(40, 32, [1.0, 1.0])
        .sides(Sides::periodic())
        .viscosity(0.002)
        .dt(0.01)
        .viscosity_mode(ViscosityMode::Explicit)
        .pressure_solver(PressureSolver::Fourier);
    let channel = Scene::builder(48, 24, [2.0, 1.0])
        .sides(Sides::channel())
        .obstacle(Obstacle::cylinder([0.6, 0.5], 0.15))
        .parabolic_inflow(1.0)
        .viscosity(0.01)
        .dt(0.01)
        .advection(Advection::MacCormack { limiter: true })
        .viscosity_mode(ViscosityMode::Implicit);
    let mixed = Scene::builder(40, 36, [1.0, 1.0])
        .sides(common::mixed_sides())
        .obstacle(Obstacle::rectangle([0.4, 0.3], [0.7, 0.65]))
        .viscosity(0.01)
        .dt(0.01)
        .pressure_solver(PressureSolver::Cg {
            rel_tol: 1e-10,
            max_iters: 2000,
        });
    vec![
        ("periodic (Fourier, explicit)", periodic.build().unwrap()),
        ("channel (MacCormack, implicit)", channel.build().unwrap()),
        ("mixed (CG)", mixed.build().unwrap()),
    ]
}

fn start(scene: &Scene) -> FlowState<f64> {
    let g = scene.grid();
    let field = |shape: [usize; 2], seed| -> Array2<f64> {
        test_array::<f64>(&shape, seed)
            .mapv(|v| 0.4 * v)
            .into_dimensionality()
            .unwrap()
    };
    FlowState::from_velocity(scene, field(g.shape_x(), 1), field(g.shape_y(), 2))
}

/// The bits of the state after three steps and of the gradients of
/// `Σ w·u_x + Σ u_y²` with respect to the start, ν, the walls and the inflow.
fn run(scene: &Scene, tape: &Tape<f64>) -> Vec<u64> {
    let v0 = FlowVars::variables(tape, &start(scene));
    let pv = ParamVars::variables(tape, &scene.params());
    let end = scene.rollout(tape, Schedule::Full, 3, &v0, &pv).unwrap();
    let w = tape.constant(test_array::<f64>(&end.ux.shape(), 3));
    let loss = end
        .ux
        .dot(w)
        .unwrap()
        .add(end.uy.mul(end.uy).unwrap().sum().unwrap())
        .unwrap();
    let wrt = [v0.ux, v0.uy, pv.viscosity, pv.wall_speed, pv.inflow];
    let grads = tape.backward(loss, &wrt).unwrap();
    let mut bits: Vec<u64> = [end.ux, end.uy, end.pressure]
        .iter()
        .flat_map(|v| v.to_array().iter().map(|x| x.to_bits()).collect::<Vec<_>>())
        .collect();
    for v in wrt {
        if let Some(g) = grads.get(v) {
            bits.extend(g.iter().map(|x| x.to_bits()));
        }
    }
    bits
}

/// A pool holding, for every field length of `scene`, buffers of NaN (and
/// of NaN pairs, the tracing velocities' layout).
fn poisoned(scene: &Scene) -> BufferPool {
    let pool = BufferPool::with_limit_bytes(1 << 30);
    let g = scene.grid();
    let lens = [g.shape_x(), g.shape_y(), g.cell_shape()].map(|[a, b]| a * b);
    pool.scope(|| {
        for len in lens {
            let held: Vec<Vec<f64>> = (0..8).map(|_| pool::take(len)).collect();
            let pairs: Vec<Vec<[f64; 2]>> = (0..4).map(|_| pool::take_or(len, [0.0; 2])).collect();
            for mut v in held {
                v.fill(f64::NAN);
                pool::recycle(v);
            }
            for mut v in pairs {
                v.fill([f64::NAN; 2]);
                pool::recycle(v);
            }
        }
    });
    assert!(pool.held_bytes() > 0);
    pool
}

#[test]
fn stale_pooled_buffers_give_the_same_bits() {
    for (name, scene) in scenes() {
        let fresh = scene.on_pool(|| run(&scene, &Tape::new()));
        assert!(
            fresh.iter().all(|&b| f64::from_bits(b).is_finite()),
            "{name}: the run without a pool is not finite"
        );
        let pool = poisoned(&scene);
        for pass in ["poisoned", "reused"] {
            let pooled = scene.on_pool(|| run(&scene, &Tape::with_pool(&pool)));
            assert_eq!(fresh.len(), pooled.len());
            let differ = fresh.iter().zip(&pooled).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "{name}, {pass} pool: {differ} values differ");
        }
        // the run's values came back to the pool for the next
        assert!(pool.held_bytes() > 0, "{name}: nothing kept");
    }
}
