//! The step's per-entry loops (advection) run on all cores in fixed blocks:
//! a step on one thread and on two gives the same bits, for the plain
//! forward and for the gradient through the step on a tape.

use diffphys_flow::{Advection, FlowState, FlowVars, Obstacle, ParamVars, Scene, Sides};
use diffphys_tape::parallel::with_threads;
use diffphys_tape::{test_array, Tape};
use ndarray::Array2;

/// A channel large enough (129 × 64 x-faces) for the loops to split.
fn scene() -> Scene {
    Scene::builder(128, 64, [2.0, 1.0])
        .sides(Sides::channel())
        .obstacle(Obstacle::cylinder([0.5, 0.5], 0.15))
        .parabolic_inflow(1.0)
        .viscosity(0.002)
        .dt(0.004)
        .advection(Advection::MacCormack { limiter: true })
        .build()
        .unwrap()
}

fn start(scene: &Scene) -> FlowState<f64> {
    let g = scene.grid();
    let field = |shape: [usize; 2], seed| -> Array2<f64> {
        test_array::<f64>(&shape, seed)
            .mapv(|v| 0.5 + 0.3 * v)
            .into_dimensionality()
            .unwrap()
    };
    FlowState::from_velocity(scene, field(g.shape_x(), 1), field(g.shape_y(), 2))
}

/// Three plain steps and the gradient of `Σ w·u` after two taped steps.
fn run(scene: &Scene) -> (Vec<u64>, Vec<u64>) {
    let p = scene.params::<f64>();
    let mut s = start(scene);
    for _ in 0..3 {
        s = scene.forward(&s, &p).unwrap().0;
    }
    let bits = |it: &mut dyn Iterator<Item = &f64>| it.map(|v| v.to_bits()).collect::<Vec<_>>();
    let forward = bits(&mut s.ux.iter().chain(s.uy.iter()).chain(s.pressure.iter()));

    let tape = Tape::<f64>::new();
    let v0 = FlowVars::variables(&tape, &start(scene));
    let pv = ParamVars::constants(&tape, &p);
    let mut v = v0.clone();
    for _ in 0..2 {
        v = scene.step(&tape, &v, &pv).unwrap().0;
    }
    let w = tape.constant(test_array::<f64>(&v.ux.shape(), 3));
    let loss = v.ux.dot(w).unwrap();
    let grads = tape.backward(loss, &[v0.ux, v0.uy]).unwrap();
    let g = bits(
        &mut grads
            .get(v0.ux)
            .unwrap()
            .iter()
            .chain(grads.get(v0.uy).unwrap().iter()),
    );
    (forward, g)
}

#[test]
fn one_thread_and_two_give_the_same_bits() {
    let scene = scene();
    let (f1, g1) = with_threads(1, || run(&scene));
    let (f2, g2) = with_threads(2, || run(&scene));
    assert!(f1.iter().any(|&b| b != 0), "the forward must move the flow");
    assert!(g1.iter().any(|&b| b != 0), "the gradient must not vanish");
    assert_eq!(f1, f2, "forward differs between 1 and 2 threads");
    assert_eq!(g1, g2, "gradient differs between 1 and 2 threads");
}
