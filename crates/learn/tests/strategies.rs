//! Every strategy on a tiny scene: the unrolled loss's gradient against finite
//! differences, checkpointed against stored unrolls, training that helps and
//! repeats per seed, and the typed errors of bad input.

mod common;

use common::*;
use diffphys_learn::*;
use diffphys_nn::{Bound, Params};
use diffphys_tape::{check_gradient, ArrayD, GradCheckOptions, Tape, Var};
use rand::Rng;

fn strategies() -> Vec<Strategy> {
    vec![
        Strategy::NonInteracting,
        Strategy::Noise { sigma: 0.05 },
        Strategy::SolverInTheLoop {
            unroll: 3,
            schedule: Schedule::Full,
        },
        Strategy::SolverInTheLoop {
            unroll: 4,
            schedule: Schedule::Every(2),
        },
        Strategy::SolverInTheLoop {
            unroll: 4,
            schedule: Schedule::Nested { branches: 2 },
        },
    ]
}

#[test]
fn every_strategy_gradient_matches_finite_differences() {
    let data = splits(1, [3, 1, 1], 8);
    let (corrector, params) = net(2, 1);
    let hybrid = Hybrid::new(Cubic, corrector);
    let t = trainer(1, 12);
    for strategy in strategies() {
        let batch = t
            .draw_batch(
                &Cubic,
                &strategy,
                &data.train,
                &mut TrainSeed(3).sampling_rng(),
            )
            .unwrap();
        assert_eq!(batch.start.batch_len(), 12 / strategy.unroll());
        let report = check_gradient(
            |tape, vars| {
                let p = Bound::from_vars(vars.to_vec());
                Trainer::batch_loss(&hybrid, tape, &p, &strategy, &batch)
            },
            params.values(),
            GradCheckOptions::for_type::<f64>(),
        )
        .unwrap();
        assert!(report.passed, "{strategy}: {report:?}");
        assert!(
            report.entries > 50,
            "{strategy}: {} entries",
            report.entries
        );
    }
}

/// The gradient of the loss of `batch` with respect to every parameter, flattened.
fn gradient(
    hybrid: &Hybrid<Cubic, Net>,
    params: &Params<f64>,
    strategy: Strategy,
    batch: &Batch,
) -> Vec<f64> {
    let tape = Tape::new();
    let p = params.bind(&tape);
    let loss = Trainer::batch_loss(hybrid, &tape, &p, &strategy, batch).unwrap();
    let grads = tape.backward(loss, p.vars()).unwrap();
    p.vars()
        .iter()
        .flat_map(|v| grads.get(*v).unwrap().iter().copied().collect::<Vec<_>>())
        .collect()
}

#[test]
fn checkpointed_and_stored_unrolls_give_the_same_gradient() {
    let data = splits(4, [3, 1, 1], 12);
    let (corrector, params) = net(5, 1);
    let hybrid = Hybrid::new(Cubic, corrector);
    let t = trainer(1, 20);
    let sol = |schedule| Strategy::SolverInTheLoop {
        unroll: 10,
        schedule,
    };
    let batch = t
        .draw_batch(
            &Cubic,
            &sol(Schedule::Full),
            &data.train,
            &mut TrainSeed(6).sampling_rng(),
        )
        .unwrap();
    let full = gradient(&hybrid, &params, sol(Schedule::Full), &batch);
    let scale = full.iter().fold(0.0f64, |m, g| m.max(g.abs()));
    assert!(scale > 1e-6);
    for schedule in [
        Schedule::Every(1),
        Schedule::Every(3),
        Schedule::Every(10),
        Schedule::Nested { branches: 2 },
        Schedule::Nested { branches: 3 },
    ] {
        let g = gradient(&hybrid, &params, sol(schedule), &batch);
        let diff = g
            .iter()
            .zip(&full)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        // The same arithmetic in another order of accumulation: round-off only.
        assert!(
            diff <= 1e-13 * scale,
            "{schedule:?}: max diff {diff:e} of {scale:e}"
        );
    }
}

#[test]
fn training_helps_every_strategy_and_repeats_per_seed() {
    let data = splits(7, [6, 3, 3], 16);
    let (corrector, _) = net(0, 1);
    let hybrid = Hybrid::new(Cubic, corrector);
    let t = trainer(100, 8);
    let coarse = rollout(&hybrid, None, &data.validation, 8).unwrap().mean();
    for strategy in [
        Strategy::NonInteracting,
        Strategy::Noise { sigma: 0.01 },
        Strategy::SolverInTheLoop {
            unroll: 4,
            schedule: Schedule::Every(2),
        },
    ] {
        let run = |seed| {
            let (_, params) = net(seed, 1);
            t.train(
                &hybrid,
                params,
                strategy,
                &data.train,
                &data.validation,
                TrainSeed(seed),
                &|| {},
            )
            .unwrap()
        };
        let a = run(11);
        let b = run(11);
        assert_eq!(
            a.model.params.values(),
            b.model.params.values(),
            "{strategy}"
        );
        assert_eq!(a.model.losses.len(), 100);
        // The untrained model at iteration 0, then every 10 iterations.
        assert_eq!(a.model.validation_curve.len(), 11);
        assert_eq!(a.model.validation_curve[0].0, 0);
        assert!(a.model.validation_failures.is_empty());
        println!(
            "{strategy}: validation {} vs coarse {coarse}",
            a.model.validation
        );
        assert!(
            a.model.validation < 0.75 * coarse,
            "{strategy}: validation {} vs coarse {coarse}",
            a.model.validation
        );
        assert_ne!(a.id(), b.id());
    }
}

#[test]
fn early_stopping_keeps_the_untrained_model_when_training_only_hurts() {
    // Training data from another physics (u ↦ 0.6 u, far from the solver and
    // from the validation reference): every trained iterate is worse on
    // validation, and the kept model is the one training started from.
    let data = splits(5, [4, 2, 1], 8);
    let wrong: Vec<Trajectory> = data
        .train
        .iter()
        .map(|tr| {
            let mut u = tr[0].fields[0].clone();
            let mut out = vec![State::from(u.clone())];
            for _ in 1..tr.len() {
                u = u.mapv(|x| 0.6 * x);
                out.push(State::from(u.clone()));
            }
            out
        })
        .collect();
    // A corrector that starts at zero: the untrained hybrid is the solver.
    let (corrector, random) = net(3, 1);
    let mut params = Params::new();
    for (name, v) in random.names().iter().zip(random.values()) {
        params.add(name.clone(), v.mapv(|_| 0.0)).unwrap();
    }
    let hybrid = Hybrid::new(Cubic, corrector);
    let trained = trainer(20, 4)
        .train(
            &hybrid,
            params.clone(),
            Strategy::NonInteracting,
            &wrong,
            &data.validation,
            TrainSeed(1),
            &|| {},
        )
        .unwrap();
    let m = trained.model;
    let curve = &m.validation_curve;
    assert_eq!(curve.iter().map(|c| c.0).collect::<Vec<_>>(), [0, 10, 20]);
    assert!(
        curve[1].1 > curve[0].1 && curve[2].1 > curve[0].1,
        "{curve:?}"
    );
    assert_eq!(m.best_iteration, 0);
    assert_eq!(m.validation, curve[0].1);
    assert_eq!(m.params.values(), params.values());
}

#[test]
fn bad_input_is_a_typed_error() {
    let data = splits(8, [2, 1, 1], 8);
    let (corrector, params) = net(0, 1);
    let hybrid = Hybrid::new(Cubic, corrector);
    let sol = |unroll| Strategy::SolverInTheLoop {
        unroll,
        schedule: Schedule::Full,
    };
    let train = |t: Trainer, s: Strategy, tr: &[Trajectory], va: &[Trajectory]| {
        t.train(&hybrid, params.clone(), s, tr, va, TrainSeed(1), &|| {})
    };
    assert!(matches!(
        train(
            trainer(0, 8),
            Strategy::NonInteracting,
            &data.train,
            &data.validation
        ),
        Err(LearnError::ZeroIterations { .. })
    ));
    assert!(matches!(
        train(trainer(5, 8), sol(0), &data.train, &data.validation),
        Err(LearnError::ZeroUnroll { .. })
    ));
    assert!(matches!(
        train(trainer(5, 8), sol(3), &data.train, &data.validation),
        Err(LearnError::Budget { .. })
    ));
    assert!(matches!(
        train(
            trainer(5, 8),
            Strategy::NonInteracting,
            &[],
            &data.validation
        ),
        Err(LearnError::EmptySplit {
            split: Split::Train,
            ..
        })
    ));
    assert!(matches!(
        train(trainer(5, 8), Strategy::NonInteracting, &data.train, &[]),
        Err(LearnError::EmptySplit {
            split: Split::Validation,
            ..
        })
    ));
    assert!(matches!(
        train(
            trainer(5, 8),
            Strategy::Noise { sigma: f64::NAN },
            &data.train,
            &data.validation
        ),
        Err(LearnError::Invalid { .. })
    ));
    // A corrector with two output channels for a one-channel state.
    let (wide, wide_params) = net(0, 2);
    let wrong = Hybrid::new(Cubic, wide);
    let result = trainer(5, 8).train(
        &wrong,
        wide_params,
        Strategy::NonInteracting,
        &data.train,
        &data.validation,
        TrainSeed(1),
        &|| {},
    );
    match result {
        Err(LearnError::CorrectorShape {
            field,
            state,
            correction,
        }) => {
            assert_eq!(field, 0);
            assert_eq!(state, vec![8, 1, CELLS]);
            assert_eq!(correction, vec![8, 2, CELLS]);
        }
        other => panic!("expected a corrector shape error, got {other:?}"),
    }
    // Every error names its cause.
    let e = train(
        trainer(0, 8),
        Strategy::NonInteracting,
        &data.train,
        &data.validation,
    )
    .unwrap_err();
    assert!(e.to_string().contains("0 training iterations"), "{e}");
}

#[test]
fn the_held_out_split_is_read_once_per_model_after_selection() {
    let data = splits(9, [4, 2, 2], 8);
    let (corrector, _) = net(0, 1);
    let hybrid = Hybrid::new(Cubic, corrector);
    let t = trainer(10, 4);
    let mut candidates = Vec::new();
    for unroll in [1, 2, 4] {
        let (_, params) = net(1, 1);
        let strategy = Strategy::SolverInTheLoop {
            unroll,
            schedule: Schedule::Full,
        };
        let trained = t
            .train(
                &hybrid,
                params,
                strategy,
                &data.train,
                &data.validation,
                TrainSeed(1),
                &|| {},
            )
            .unwrap();
        let v = trained.model.validation;
        candidates.push(Candidate::new(strategy.name(), trained, v));
    }
    let copy = candidates[0].clone();
    let selection = select_best(candidates).unwrap();
    let best = selection
        .models
        .iter()
        .map(|m| m.validation())
        .fold(f64::INFINITY, f64::min);
    assert_eq!(selection.models[selection.chosen].validation(), best);
    for model in selection.models {
        data.held_out()
            .evaluate(model, |m, d| {
                Ok(rollout(&hybrid, Some(&m.params), d, 8)?.mean())
            })
            .unwrap();
    }
    // The same trained model, cloned and selected again, is refused.
    let again = select_best(vec![copy]).unwrap().models.remove(0);
    assert!(matches!(
        data.held_out().evaluate(again, |_, _| Ok(())),
        Err(LearnError::HeldOutReused { .. })
    ));
}

/// A step whose state holds a parameter in entry 0 that must stay 1 (a state
/// that packs a parameter into its field): anything else is refused, so the
/// simulator's own perturbation must leave it alone.
struct Pinned {
    protect: bool,
}

impl Simulator for Pinned {
    fn step<'t>(&self, u: &StateVars<'t>) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        let u = u.only()?;
        let values = u.to_array();
        if values.iter().step_by(CELLS).any(|&p| p != 1.0) {
            return Err(diffphys_tape::TapeError::invalid(
                "pinned step",
                "the parameter entry was perturbed",
            ));
        }
        Ok(vec![u.mul(u.tape().constant(pin_mask(&u.shape(), 0.9)))?])
    }

    fn perturb(&self, state: &mut State, sigma: f64, rng: &mut rand::rngs::StdRng) {
        for (i, x) in state.fields[0].iter_mut().enumerate() {
            let noise = sigma * standard_normal(rng);
            if !self.protect || i % CELLS != 0 {
                *x += noise;
            }
        }
    }
}

/// `factor` everywhere but 1 at entry 0 of every sample.
fn pin_mask(shape: &[usize], factor: f64) -> ArrayD<f64> {
    let last = shape.len() - 1;
    ArrayD::from_shape_fn(shape.to_vec(), |i| if i[last] == 0 { 1.0 } else { factor })
}

/// The test's network with its output zero at entry 0.
struct PinnedNet(Net);

impl Corrector for PinnedNet {
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        u: &StateVars<'t>,
    ) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        let shape = u.only()?.shape();
        let mask = pin_mask(&shape, 1.0) - pin_mask(&shape, 0.0);
        let mask = u.only()?.tape().constant(mask);
        Ok(vec![self.0.correction(p, u)?[0].mul(mask)?])
    }
}

#[test]
fn noise_goes_through_the_simulators_perturbation() {
    let data = Splits::generate(DataSeed(9), [2, 1, 1], |_, n, rng| {
        Ok((0..n)
            .map(|_| {
                let mut u = ArrayD::from_shape_fn(vec![1, CELLS], |i| {
                    if i[1] == 0 {
                        1.0
                    } else {
                        rng.random_range(-1.0..1.0)
                    }
                });
                let mut tr = vec![State::from(u.clone())];
                for _ in 0..8 {
                    u = &u * &pin_mask(&[1, CELLS], 0.92);
                    tr.push(State::from(u.clone()));
                }
                tr
            })
            .collect::<Vec<Trajectory>>())
    })
    .unwrap();
    let t = trainer(3, 4);
    let strategy = Strategy::Noise { sigma: 0.5 };
    for protect in [true, false] {
        let (corrector, params) = net(8, 1);
        let hybrid = Hybrid::new(Pinned { protect }, PinnedNet(corrector));
        let result = t.train(
            &hybrid,
            params,
            strategy,
            &data.train,
            &data.validation,
            TrainSeed(1),
            &|| {},
        );
        assert_eq!(result.is_ok(), protect, "protect {protect}: {result:?}");
    }
}

#[test]
fn a_rollout_measures_the_scene_metrics_beside_the_relative_error() {
    let s = splits(4, [2, 2, 2], 6);
    let (c, params) = net(3, 1);
    let hybrid = Hybrid::new(Cubic, c);
    let plain = rollout(&hybrid, Some(&params), &s.validation, 5).unwrap();
    assert!(plain.measured.is_empty());
    // The relative L2 error as a scene metric gives the same figures; the
    // largest absolute deviation is another.
    type Fields<'a, 'b> = &'a [ndarray::ArrayViewD<'b, f64>];
    let same = |p: Fields<'_, '_>, r: Fields<'_, '_>| {
        relative_l2(
            &p[0].to_owned().insert_axis(ndarray::Axis(0)),
            &r[0].to_owned().insert_axis(ndarray::Axis(0)),
        )
    };
    let worst = |p: Fields<'_, '_>, r: Fields<'_, '_>| {
        p[0].iter()
            .zip(r[0].iter())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    let measured =
        rollout_measured(&hybrid, Some(&params), &s.validation, 5, &[&same, &worst]).unwrap();
    assert_eq!(measured.per_step, plain.per_step);
    assert_eq!(measured.last, plain.last);
    assert_eq!(measured.measured.len(), 2);
    for (a, b) in measured.measured[0].iter().zip(&plain.per_step) {
        assert!((a - b).abs() <= 1e-15 * b.abs());
    }
    assert!(measured.measured[1].iter().all(|&w| w > 0.0));
    assert_eq!(measured.measured_mean(0).map(|m| m > 0.0), Some(true));
    assert_eq!(measured.measured_mean(2), None);
    // A metric that is not defined on these states is refused, not averaged.
    let undefined = |_: Fields<'_, '_>, _: Fields<'_, '_>| f64::NAN;
    let refused = rollout_measured(&hybrid, Some(&params), &s.validation, 5, &[&undefined]);
    assert!(matches!(refused, Err(LearnError::Invalid { .. })));
}
