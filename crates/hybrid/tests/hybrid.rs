//! The hybrid flow pieces on a small channel past a body: the simulator's
//! noise and pinned-face measurements, the lattice corrector's gradient
//! through a corrected step against central differences, and the flow
//! metrics.

use diffphys_flow::{Boundary, FlowParams, FlowState, Obstacle, PressureSolver, Scene, Sides};
use diffphys_hybrid::metrics::{deviation_error, vorticity_error};
use diffphys_hybrid::{free_faces, sample, FlowSimulator, HybridError, LatticeNet, NetSize};
use diffphys_learn::{Hybrid, Simulator, State, StateVars, TrainSeed};
use diffphys_nn::{Arithmetic, Bound, Params};
use diffphys_tape::{check_gradient, ArrayD, GradCheckOptions};
use ndarray::{Array2, Axis};
use rand::SeedableRng;

/// A 12 × 6 channel (inflow left, outflow right, free-slip walls) past a
/// block, plain splitting.
fn channel() -> Scene {
    channel_at(12, 6, 0.02)
}

/// The same channel at `nx × ny` cells and time step `dt`.
fn channel_at(nx: usize, ny: usize, dt: f64) -> Scene {
    Scene::builder(nx, ny, [2.0, 1.0])
        .sides(Sides {
            left: Boundary::inflow(),
            right: Boundary::outflow(),
            bottom: Boundary::free_slip(),
            top: Boundary::free_slip(),
        })
        .obstacle(Obstacle::Rectangle {
            lo: [0.4, 0.3],
            hi: [0.8, 0.7],
        })
        .uniform_inflow(1.0)
        .dt(dt)
        .splitting(diffphys_flow::Splitting::Plain)
        .pressure_solver(PressureSolver::Cholesky)
        .build()
        .unwrap()
}

/// A state with some structure: the free stream plus a smooth cross flow,
/// made a state of `scene` by one step.
fn state(scene: &Scene) -> FlowState<f64> {
    let g = scene.grid();
    let uy = Array2::from_shape_fn(g.shape_y(), |(i, j)| {
        0.2 * (0.7 * i as f64 + 0.4 * j as f64).sin()
    });
    let s = FlowState::from_velocity(scene, Array2::from_elem(g.shape_x(), 1.0), uy);
    scene.forward(&s, &scene.params()).unwrap().0
}

/// The solver of `scene` with the smallest corrector (two channels, no
/// residual block), its head at zero.
fn tiny_hybrid(scene: &Scene) -> (Hybrid<FlowSimulator, LatticeNet>, Params<f64>) {
    let size = NetSize {
        width: 2,
        blocks: 0,
    };
    let mut rng = TrainSeed(1).init_rng();
    let (net, params) = LatticeNet::new(scene, size, code, Arithmetic::Native, &mut rng).unwrap();
    (Hybrid::new(FlowSimulator::new(scene.clone()), net), params)
}

/// The corrector's viscosity channel: the log of a Reynolds number.
fn code(nu: f64) -> f64 {
    (0.2 / nu / 400.0).ln()
}

#[test]
fn noise_lands_on_free_faces_only_and_repeats_per_seed() {
    let sim = FlowSimulator::new(channel());
    let s = State::stack(&[&sim.sample(&state(sim.scene()), 1e-3)]).unwrap();
    let noisy = |seed| {
        let mut n = s.clone();
        sim.perturb(&mut n, 0.1, &mut rand::rngs::StdRng::seed_from_u64(seed));
        n
    };
    let (a, b) = (noisy(3), noisy(3));
    assert_eq!(a, b, "the same seed draws the same noise");
    let free = free_faces(sim.scene());
    let (mut moved, mut kept) = (0, 0);
    for (c, (n, o)) in a.fields.iter().zip(&s.fields).take(2).enumerate() {
        let (n, o) = (n.index_axis(Axis(0), 0), o.index_axis(Axis(0), 0));
        for ((idx, x), y) in n.indexed_iter().zip(o.iter()) {
            let f = free[[c, idx[0], idx[1]]];
            if f == 0.0 {
                assert_eq!(x, y, "a pinned face moved at {c} {idx:?}");
                kept += 1;
            } else if x != y {
                moved += 1;
            }
        }
    }
    assert!(moved > 50 && kept > 10, "moved {moved}, kept {kept}");
    assert_eq!(a.params, s.params, "the viscosity is not noised");
    // A state that is not a batch of velocity pairs is left as it is (the
    // trainer refuses it before it would perturb it), not a panic.
    let mut odd = State::new(vec![ArrayD::zeros(vec![3, 3])], vec![]);
    sim.perturb(&mut odd, 0.1, &mut rand::rngs::StdRng::seed_from_u64(1));
    assert_eq!(odd.fields[0], ArrayD::<f64>::zeros(vec![3, 3]));
}

#[test]
fn pinned_faces_of_the_solvers_own_state_carry_no_error() {
    let sim = FlowSimulator::new(channel());
    let s0 = sim.sample(&state(sim.scene()), 2e-3);
    let s1 = State::new(
        sim.step_plain(&State::stack(&[&s0]).unwrap())
            .unwrap()
            .into_iter()
            .map(|f| f.index_axis_move(Axis(0), 0))
            .collect(),
        s0.params.clone(),
    );
    // Its own next state: no error anywhere.
    assert_eq!(
        sim.pinned_face_error(&[s0.clone(), s1.clone()]).unwrap(),
        0.0
    );
    assert_eq!(
        sim.one_step_rms(&[vec![s0.clone(), s1.clone()]], 1)
            .unwrap(),
        0.0
    );
    // A target that differs on a wall face is pinned-face error; one that
    // differs on a free face is not.
    let mut wall = s1.clone();
    wall.fields[1][[3, 0]] += 0.5;
    assert!(sim.pinned_face_error(&[s0.clone(), wall]).unwrap() > 0.0);
    let mut inner = s1.clone();
    inner.fields[0][[1, 1]] += 0.5;
    assert_eq!(
        sim.pinned_face_error(&[s0.clone(), inner.clone()]).unwrap(),
        0.0
    );
    assert!(sim.one_step_rms(&[vec![s0.clone(), inner]], 1).unwrap() > 0.0);
    assert!(matches!(
        sim.one_step_rms(&[vec![s0]], 1),
        Err(HybridError::Trajectory { .. })
    ));
}

#[test]
fn the_corrected_step_passes_central_differences() {
    let scene = channel();
    let sim = FlowSimulator::new(scene.clone());
    let size = NetSize {
        width: 3,
        blocks: 1,
    };
    let mut rng = TrainSeed(2).init_rng();
    let (net, zero_head) =
        LatticeNet::new(&scene, size, code, Arithmetic::Native, &mut rng).unwrap();
    // A head away from zero, so that every layer's parameters matter.
    let mut params = Params::new();
    for (name, v) in zero_head.names().iter().zip(zero_head.values()) {
        params.add(name.clone(), v.mapv(|x| x + 0.05)).unwrap();
    }
    let hybrid = Hybrid::new(sim.clone(), net);
    let s = State::stack(&[
        &sim.sample(&state(&scene), 2e-3),
        &sim.sample(&state(&scene), 4e-3),
    ])
    .unwrap();
    let np = params.values().len();
    let mut inputs: Vec<ArrayD<f64>> = params.values().to_vec();
    inputs.extend(s.fields.iter().cloned());
    // The viscosity enters the network as data (its code channel is not on
    // the tape), so it is held constant here; the solver's gradient with
    // respect to it is flow's own test (crates/flow/tests/batch.rs).
    let nu = s.params.clone();
    let weights: Vec<ArrayD<f64>> = s
        .fields
        .iter()
        .map(|f| f.mapv(|x| (3.0 * x).sin()))
        .collect();
    let check = check_gradient(
        |tape, v| {
            let p = Bound::from_vars(v[..np].to_vec());
            let u = StateVars {
                fields: v[np..np + 2].to_vec(),
                params: nu.iter().map(|a| tape.constant(a.clone())).collect(),
            };
            let next = hybrid.step(Some(&p), &u)?.fields;
            let mut loss = tape.scalar(0.0);
            for (f, w) in next.iter().zip(&weights) {
                loss = loss.add(f.mul(tape.constant(w.clone()))?.powi(2)?.sum()?)?;
            }
            Ok(loss)
        },
        &inputs,
        GradCheckOptions::for_type::<f64>(),
    )
    .unwrap();
    assert!(check.passed, "{check:?}");
    assert!(check.entries > 200, "{check:?}");
    // The parameters and both fields all matter.
    assert_eq!(inputs.len(), np + 2);
}

#[test]
fn a_zero_head_starts_as_the_solver_and_sizes_parse() {
    let scene = channel();
    let sim = FlowSimulator::new(scene.clone());
    let size: NetSize = "w4b2".parse().unwrap();
    assert_eq!(
        (size.width, size.blocks, size.label()),
        (4, 2, "w4b2".to_string())
    );
    for bad in ["w0b1", "4b2", "w4", "wxb2"] {
        assert!(
            matches!(bad.parse::<NetSize>(), Err(HybridError::Size { .. })),
            "{bad}"
        );
    }
    let (net, params) = LatticeNet::new(
        &scene,
        size,
        code,
        Arithmetic::Native,
        &mut TrainSeed(1).init_rng(),
    )
    .unwrap();
    let hybrid = Hybrid::new(sim.clone(), net);
    let s = State::stack(&[&sim.sample(&state(&scene), 2e-3)]).unwrap();
    assert_eq!(
        hybrid.step_plain(Some(&params), &s).unwrap(),
        hybrid.step_plain(None, &s).unwrap()
    );
}

#[test]
fn the_deviation_and_vorticity_errors_measure_the_wake_not_the_free_stream() {
    let scene = channel();
    let g = scene.grid();
    // A reference: the free stream plus a cross-stream wave; a prediction:
    // the free stream alone (it misses the whole wake).
    let wave = Array2::from_shape_fn(g.shape_y(), |(i, j)| {
        (0.3 * i as f64 + 0.7 * j as f64).sin()
    });
    let fields = |uy: Array2<f64>| {
        let s = FlowState::from_velocity(&scene, Array2::from_elem(g.shape_x(), 1.0), uy);
        scene.sample_of(&s)
    };
    let (r, p) = (fields(0.1 * &wave), fields(Array2::zeros(g.shape_y())));
    let rv: Vec<_> = r.iter().map(|a| a.view()).collect();
    let pv: Vec<_> = p.iter().map(|a| a.view()).collect();
    assert_eq!(deviation_error(&scene, [1.0, 0.0], &rv, &rv), 0.0);
    assert_eq!(vorticity_error(&scene, &rv, &rv), 0.0);
    // Missing the whole deviation is an error of 1 (100 %), however small the
    // wave is against the free stream; the state's relative error is not.
    let missed = deviation_error(&scene, [1.0, 0.0], &pv, &rv);
    assert!((missed - 1.0).abs() < 1e-12, "{missed}");
    let batch = |f: &[ArrayD<f64>]| {
        f.iter()
            .map(|a| a.clone().insert_axis(Axis(0)))
            .collect::<Vec<_>>()
    };
    let whole = diffphys_learn::relative_l2_fields(&batch(&p), &batch(&r));
    assert!(whole < 0.2 * missed, "{whole}");
    assert!(vorticity_error(&scene, &pv, &rv) > 0.5);
    // Not a state of the scene: NaN, which the rollout refuses.
    let wrong = ArrayD::<f64>::zeros(vec![3, 3]);
    let wrong = [wrong.view(), wrong.view()];
    assert!(deviation_error(&scene, [1.0, 0.0], &wrong, &rv).is_nan());
    assert!(vorticity_error(&scene, &rv, &wrong).is_nan());
    // The sample the metric reads is the simulator's.
    let s = sample(&scene, &FlowState::zeros(&scene), 1e-3);
    assert_eq!(s.fields.len(), scene.batch_fields());
}

#[test]
fn the_speed_study_measures_every_solver_on_the_same_cases() {
    use diffphys_hybrid::speed::{corrected, finer, Case};
    let scene = channel();
    let (hybrid, params) = tiny_hybrid(&scene);
    let p = FlowParams {
        viscosity: 2e-3,
        ..scene.params()
    };
    let start = state(&scene);
    let mut targets = vec![];
    let mut s = start.clone();
    for _ in 0..3 {
        s = scene.forward(&s, &p).unwrap().0;
        targets.push(s.clone());
    }
    let case = Case {
        viscosity: 2e-3,
        fine_start: (start.ux.view(), start.uy.view()),
        fine_factor: 1,
        coarse_start: &start,
        targets: &targets,
        free_stream: [1.0, 0.0],
    };
    // Against its own trajectory, the solver alone is exact, by either path;
    // the zero-head corrector too.
    let alone = corrected(&hybrid, None, &[case]).unwrap();
    let same = finer(&scene, 1, scene.grid(), &[case]).unwrap();
    assert_eq!((alone.rel_error, same.rel_error), (0.0, 0.0));
    assert_eq!(
        corrected(&hybrid, Some(&params), &[case])
            .unwrap()
            .rel_error,
        0.0
    );
    // Against a shifted reference, both see the same error.
    let shifted: Vec<_> = targets
        .iter()
        .map(|t| FlowState {
            ux: t.ux.mapv(|x| x + 0.1),
            ..t.clone()
        })
        .collect();
    let case = Case {
        targets: &shifted,
        ..case
    };
    let (a, b) = (
        corrected(&hybrid, None, &[case]).unwrap(),
        finer(&scene, 1, scene.grid(), &[case]).unwrap(),
    );
    assert!(
        a.rel_error > 0.01 && a.rel_error == b.rel_error,
        "{a:?} {b:?}"
    );
    // The deviation's error has the same numerator over the wake alone:
    // larger than the state's, the same by either path.
    assert!(a.deviation_error > a.rel_error && a.deviation_error == b.deviation_error);
    // A level that does not divide the start's factor, or nothing to time.
    assert!(matches!(
        finer(&scene, 2, scene.grid(), &[case]),
        Err(HybridError::Trajectory { .. })
    ));
    assert!(matches!(
        corrected(&hybrid, None, &[]),
        Err(HybridError::Trajectory { .. })
    ));
}

#[test]
fn a_reference_records_restricts_round_trips_and_scores_a_rollout() {
    use diffphys_hybrid::reference::{evaluate, Evaluation, Recorder, Reference};
    let coarse = channel();
    let p = FlowParams {
        viscosity: 2e-3,
        ..coarse.params()
    };
    // The coarse scene as its own reference (factor 1): the solver alone
    // reproduces it exactly.
    let mut seen = 0;
    let recorder = Recorder {
        fine: &coarse,
        coarse: &coarse,
        factor: 1,
        warm: 2,
        record: 6,
        starts: &[0, 2],
    };
    let start = state(&coarse);
    let r = recorder
        .record(&start, (100.0, p.viscosity), &|_| {}, &mut |_| {
            seen += 1;
            Ok(())
        })
        .unwrap();
    assert_eq!((r.states.len(), r.fine_starts.len(), seen), (7, 2, 7));
    let back =
        Reference::from_arrays(r.to_arrays().unwrap(), &coarse, (100.0, p.viscosity)).unwrap();
    assert_eq!(back, r);
    assert!(matches!(
        r.window(&coarse, 3, 5),
        Err(HybridError::Trajectory { .. })
    ));
    let (hybrid, params) = tiny_hybrid(&coarse);
    let e = Evaluation {
        starts: &[0, 2],
        rollout: 3,
        long: 6,
        free_stream: [1.0, 0.0],
    };
    let alone = evaluate(&hybrid, None, &r, &e).unwrap();
    assert_eq!((alone.mean, alone.long, alone.deviation), (0.0, 0.0, 0.0));
    assert_eq!(alone.curve.len(), 3);
    assert_eq!(alone.last.ux, r.states[6].ux);
    // The speed study's cases come from the recorded starts; the solver alone
    // is exact on them, and a start that was not recorded, or a rollout past
    // the record, is refused.
    use diffphys_hybrid::speed::{cases, corrected, Table};
    let free = [1.0, 0.0];
    let c = cases(std::slice::from_ref(&r), (&[0, 2], &[2]), 1, 3, free).unwrap();
    assert_eq!((c.len(), c[0].targets.len()), (1, 3));
    assert_eq!(c[0].targets[0], r.states[3]);
    let timed = corrected(&hybrid, None, &c).unwrap();
    assert_eq!(timed.rel_error, 0.0);
    for (speed_starts, rollout) in [(&[1][..], 3), (&[2][..], 5)] {
        assert!(matches!(
            cases(
                std::slice::from_ref(&r),
                (&[0, 2], speed_starts),
                1,
                rollout,
                free
            ),
            Err(HybridError::Trajectory { .. })
        ));
    }
    let mut table = Table::default();
    table.push("alone", 1, timed);
    assert_eq!(table.get("alone").map(|row| row.level), Some(1));
    assert_eq!(table.rows_json()[0]["rel_error"], 0.0);
    assert_eq!(table.rows_json()[0]["deviation_error"], 0.0);
    // A corrector that moves the state scores above zero.
    let mut moved = Params::new();
    for (name, v) in params.names().iter().zip(params.values()) {
        moved.add(name.clone(), v.mapv(|x| x + 0.05)).unwrap();
    }
    let corrected = evaluate(&hybrid, Some(&moved), &r, &e).unwrap();
    assert!(corrected.mean > 0.0 && corrected.vorticity > 0.0);
    // A finer recording restricts to the coarse grid.
    let fine = channel_at(24, 12, 0.01);
    let fine_start = FlowState::from_velocity(
        &fine,
        Array2::from_elem(fine.grid().shape_x(), 1.0),
        Array2::zeros(fine.grid().shape_y()),
    );
    let r2 = Recorder {
        fine: &fine,
        factor: 2,
        ..recorder
    }
    .record(&fine_start, (100.0, p.viscosity), &|_| {}, &mut |_| Ok(()))
    .unwrap();
    assert_eq!(r2.states[0].ux.shape(), start.ux.shape());
    assert_eq!(r2.fine_starts[0].0.shape(), fine_start.ux.shape());
}
