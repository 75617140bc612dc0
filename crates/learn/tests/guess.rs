//! The learned initial guess on a tiny Poisson problem: the gradient of both
//! losses against finite differences, training that cuts iterations, and the
//! typed errors of bad input.

use diffphys_learn::guess::*;
use diffphys_learn::{DataSeed, LearnError, LrSchedule, Split, TrainSeed};
use diffphys_nn::{Activation, Bound, Layer, Padding, Params, UNet, UNetConfig};
use diffphys_ops::cg::{conjugate_gradient, CgParams};
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::{Boundary, Grid2};
use diffphys_tape::{check_gradient, ArrayD, GradCheckOptions, Tape, Var};
use rand::rngs::StdRng;
use rand::Rng;

const N: usize = 8;

struct Guess(UNet);

impl InitialGuess for Guess {
    fn guess<'t>(
        &self,
        p: &Bound<'t, f64>,
        b: Var<'t, f64>,
    ) -> diffphys_tape::Result<Var<'t, f64>> {
        // A⁻¹ of the lowest mode is 1/(2π²) ≈ 0.05: the network works on O(1) values.
        self.0.forward(p, b)?.mul_scalar(0.05)
    }
}

fn laplacian() -> Laplacian2 {
    Laplacian2::negative(Grid2::square(N, N, 1.0 / N as f64, Boundary::ZeroDirichlet).unwrap())
}

fn network(seed: u64, perturb: bool) -> (Guess, Params<f64>) {
    let mut params = Params::<f64>::new();
    let config = UNetConfig {
        dims: 2,
        c_in: 1,
        c_out: 1,
        widths: vec![2, 2],
        kernel: 3,
        padding: Padding::Zero,
        activation: Activation::Identity,
    };
    let net = UNet::new(&mut params, "g", config, &mut TrainSeed(seed).init_rng()).unwrap();
    if !perturb {
        return (Guess(net), params);
    }
    // Non-zero head, so that every parameter has a gradient.
    let mut rng = TrainSeed(seed + 1).init_rng();
    let mut perturbed = Params::new();
    for (name, v) in params.names().iter().zip(params.values()) {
        perturbed
            .add(
                name.clone(),
                v.mapv(|x| x + 0.1 * rng.random_range(-1.0f64..1.0)),
            )
            .unwrap();
    }
    (Guess(net), perturbed)
}

/// A random right-hand side of the lowest 4 × 4 sine modes and its solution.
fn draw(rng: &mut StdRng) -> Result<GuessProblem, LearnError> {
    let lap = laplacian();
    let c: Vec<f64> = (0..16).map(|_| rng.random_range(-1.0..1.0)).collect();
    let b = ArrayD::from_shape_fn(vec![N, N], |ix| {
        let (x, y) = (
            (ix[0] as f64 + 0.5) / N as f64,
            (ix[1] as f64 + 0.5) / N as f64,
        );
        let pi = std::f64::consts::PI;
        (0..16)
            .map(|m| {
                c[m] * (pi * (m / 4 + 1) as f64 * x).sin() * (pi * (m % 4 + 1) as f64 * y).sin()
            })
            .sum::<f64>()
    });
    let mut x = ArrayD::zeros(vec![N, N]);
    conjugate_gradient(
        &lap,
        b.view(),
        x.view_mut(),
        &CgParams::default().with_rel_tol(1e-12),
    )?;
    Ok(GuessProblem { b, x_star: x })
}

fn problems(split: Split, count: usize) -> Vec<GuessProblem> {
    let mut rng = DataSeed(1).rng(split);
    (0..count).map(|_| draw(&mut rng).unwrap()).collect()
}

#[test]
fn both_losses_have_the_gradient_of_finite_differences() {
    let (g, params) = network(2, true);
    let lap = laplacian();
    let batch = problems(Split::Train, 2);
    let refs: Vec<&GuessProblem> = batch.iter().collect();
    for loss in [
        GuessLoss::Supervised,
        GuessLoss::ThroughSolver { iterations: 3 },
    ] {
        let report = check_gradient(
            |tape, vars| {
                let p = Bound::from_vars(vars.to_vec());
                guess_loss(tape, &lap, &g, &p, loss, &refs)
                    .map_err(|e| diffphys_tape::TapeError::invalid("guess loss", e.to_string()))
            },
            params.values(),
            GradCheckOptions::for_type::<f64>(),
        )
        .unwrap();
        assert!(report.passed, "{loss:?}: {report:?}");
    }
}

#[test]
fn the_unrolled_residual_is_the_true_residual() {
    let lap = laplacian();
    let p = problems(Split::Train, 1).remove(0);
    let a = std::sync::Arc::new(PerSample::new(lap.clone(), 1));
    let tape = Tape::new();
    let b = tape.constant(
        p.b.clone()
            .insert_axis(ndarray::Axis(0))
            .insert_axis(ndarray::Axis(0)),
    );
    let x0 = tape.constant(ArrayD::zeros(vec![1, 1, N, N]));
    let r = unrolled_cg_residual(&a, b, x0, 3).unwrap().to_array();
    let mut x = ArrayD::zeros(vec![N, N]);
    conjugate_gradient(
        &lap,
        p.b.view(),
        x.view_mut(),
        &CgParams::default().fixed_iterations(3),
    )
    .unwrap();
    let measured = true_relative_residual(&lap, &p.b, &x).unwrap();
    let norm = |a: &ArrayD<f64>| a.iter().map(|v| v * v).sum::<f64>().sqrt();
    let recorded = norm(&r) / norm(&p.b);
    assert!(
        (recorded - measured).abs() <= 1e-10 * measured.max(1e-300),
        "{recorded} vs {measured}"
    );
}

fn guess_trainer(steps: usize, batch: usize) -> GuessTrainer {
    GuessTrainer {
        steps,
        batch,
        learning_rate: 1e-2,
        schedule: LrSchedule::Cosine {
            final_fraction: 0.01,
        },
        validate_every: 20,
        validation_tolerances: vec![1e-1, 1e-2],
    }
}

#[test]
fn training_through_cg_cuts_iterations_and_repeats() {
    let lap = laplacian();
    let validation = problems(Split::Validation, 4);
    let (g, _) = network(0, false);
    let zero = mean_iterations(&lap, &g, None, &validation, &[1e-1, 1e-2]).unwrap();
    let run = || {
        let (_, params) = network(3, false);
        guess_trainer(100, 4)
            .train(
                &lap,
                &g,
                params,
                GuessLoss::ThroughSolver { iterations: 2 },
                &mut draw,
                DataSeed(1).rng(Split::Train),
                &validation,
                &|| {},
            )
            .unwrap()
    };
    let (a, b) = (run(), run());
    assert_eq!(a.model.params.values(), b.model.params.values());
    println!("trained {} vs zero {zero}", a.model.validation);
    assert!(
        a.model.validation < zero,
        "{} vs zero guess {zero}",
        a.model.validation
    );
}

#[test]
fn bad_input_is_a_typed_error() {
    let lap = laplacian();
    let validation = problems(Split::Validation, 2);
    let (g, params) = network(0, true);
    let train = |t: GuessTrainer, loss, v: &[GuessProblem]| {
        t.train(
            &lap,
            &g,
            params.clone(),
            loss,
            &mut draw,
            DataSeed(1).rng(Split::Train),
            v,
            &|| {},
        )
    };
    let through = GuessLoss::ThroughSolver { iterations: 2 };
    assert!(matches!(
        train(guess_trainer(0, 2), through, &validation),
        Err(LearnError::ZeroIterations { .. })
    ));
    assert!(matches!(
        train(guess_trainer(5, 0), through, &validation),
        Err(LearnError::Budget { .. })
    ));
    assert!(matches!(
        train(
            guess_trainer(5, 2),
            GuessLoss::ThroughSolver { iterations: 0 },
            &validation
        ),
        Err(LearnError::ZeroUnroll { .. })
    ));
    assert!(matches!(
        train(guess_trainer(5, 2), through, &[]),
        Err(LearnError::EmptySplit {
            split: Split::Validation,
            ..
        })
    ));
}

/// The supervised trainer's typed errors and early stopping.
mod supervised {
    use diffphys_learn::{
        mean_squared_error, DataSeed, LearnError, LrSchedule, Pair, PairSource, Split,
        SupervisedTrainer,
    };
    use diffphys_nn::{Activation, Padding, Params, UNet, UNetConfig};
    use diffphys_tape::ArrayD;
    use rand::rngs::StdRng;
    use rand::Rng;

    fn pair(rng: &mut StdRng) -> Result<Pair, LearnError> {
        let input = ArrayD::from_shape_fn(vec![1, 8], |_| rng.random_range(-1.0..1.0));
        let target = input.mapv(|x| 0.5 * x);
        Ok(Pair { input, target })
    }

    fn setup() -> (UNet, Params<f64>) {
        let mut params = Params::<f64>::new();
        let config = UNetConfig {
            dims: 1,
            c_in: 1,
            c_out: 1,
            widths: vec![2],
            kernel: 3,
            padding: Padding::Periodic,
            activation: Activation::Identity,
        };
        let net = UNet::new(&mut params, "s", config, &mut DataSeed(0).rng(Split::Train)).unwrap();
        (net, params)
    }

    fn trainer(steps: usize, batch: usize) -> SupervisedTrainer {
        SupervisedTrainer {
            steps,
            batch,
            learning_rate: 1e-2,
            schedule: LrSchedule::Constant,
            validate_every: 10,
        }
    }

    #[test]
    fn fits_and_refuses_bad_input() {
        let (net, params) = setup();
        let mut rng = DataSeed(1).rng(Split::Validation);
        let validation: Vec<Pair> = (0..4).map(|_| pair(&mut rng).unwrap()).collect();
        let fixed: Vec<Pair> = (0..8).map(|_| pair(&mut rng).unwrap()).collect();
        let before = mean_squared_error(&net, &params, &validation).unwrap();
        let t = trainer(50, 4)
            .train(
                &net,
                params.clone(),
                PairSource::Fixed(&fixed),
                &mut DataSeed(2).rng(Split::Train),
                &validation,
                &|| {},
            )
            .unwrap();
        assert!(
            t.model.validation < 0.1 * before,
            "{} vs {before}",
            t.model.validation
        );
        assert_eq!(t.model.validation_curve.len(), 5);
        let mut draw = pair;
        let run = |t: SupervisedTrainer, source: PairSource<'_>, v: &[Pair]| {
            t.train(
                &net,
                params.clone(),
                source,
                &mut DataSeed(2).rng(Split::Train),
                v,
                &|| {},
            )
        };
        assert!(matches!(
            run(trainer(0, 4), PairSource::Fixed(&fixed), &validation),
            Err(LearnError::ZeroIterations { .. })
        ));
        assert!(matches!(
            run(trainer(5, 0), PairSource::Stream(&mut draw), &validation),
            Err(LearnError::Budget { .. })
        ));
        assert!(matches!(
            run(trainer(5, 4), PairSource::Fixed(&[]), &validation),
            Err(LearnError::EmptySplit {
                split: Split::Train,
                ..
            })
        ));
        assert!(matches!(
            run(trainer(5, 4), PairSource::Fixed(&fixed), &[]),
            Err(LearnError::EmptySplit {
                split: Split::Validation,
                ..
            })
        ));
    }
}
