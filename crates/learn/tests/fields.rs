//! A state of several fields with per-sample parameters: two physical fields
//! of different shapes, an auxiliary the solver carries, and a viscosity per
//! sample. The unrolled loss's gradient matches finite differences, the loss
//! is the mean over every entry of the physical fields, the input noise leaves
//! the auxiliary and the parameters alone, and training helps.

use std::collections::HashSet;
use std::rc::Rc;

use diffphys_learn::*;
use diffphys_nn::{Activation, Bound, Layer, Padding, Params, UNet, UNetConfig};
use diffphys_tape::{check_gradient, ArrayD, GradCheckOptions, Tape, Var};
use rand::Rng;

const A: usize = 8;
const C: usize = 4;

/// `a' = 0.9 a − ν a − 0.05 a³ + 0.05 p`, `c' = 0.8 c`, `p' = a`: a two-level
/// step in `a` (its previous value `p` is the auxiliary), `ν` per sample.
struct TwoLevel;

impl Simulator for TwoLevel {
    fn auxiliary_fields(&self) -> usize {
        1
    }

    fn step<'t>(&self, s: &StateVars<'t>) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        let [a, c, p] = [s.fields[0], s.fields[1], s.fields[2]];
        let nu = s.params[0];
        let a_next = a
            .mul_scalar(0.9)?
            .sub(nu.mul(a)?)?
            .sub(a.powi(3)?.mul_scalar(0.05)?)?
            .add(p.mul_scalar(0.05)?)?;
        Ok(vec![a_next, c.mul_scalar(0.8)?, a])
    }
}

/// The reference: the same with `0.95`, `0.04` and `0.85`.
fn reference(s: &State) -> State {
    let [a, c, p] = [&s.fields[0], &s.fields[1], &s.fields[2]];
    let nu = &s.params[0];
    let a_next = a.mapv(|x| 0.95 * x - 0.04 * x.powi(3)) - nu * a + p * 0.05;
    State::new(vec![a_next, c * 0.85, a.clone()], s.params.clone())
}

/// One network per physical field.
struct Nets(UNet, UNet);

impl Corrector for Nets {
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        s: &StateVars<'t>,
    ) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        Ok(vec![
            self.0.forward(p, s.fields[0])?,
            self.1.forward(p, s.fields[1])?,
        ])
    }
}

fn nets(seed: u64) -> (Nets, Params<f64>) {
    let config = UNetConfig {
        dims: 1,
        c_in: 1,
        c_out: 1,
        widths: vec![3],
        kernel: 3,
        padding: Padding::Periodic,
        activation: Activation::Tanh,
    };
    let mut params = Params::<f64>::new();
    let mut rng = TrainSeed(seed).init_rng();
    let a = UNet::new(&mut params, "a", config.clone(), &mut rng).unwrap();
    let c = UNet::new(&mut params, "c", config, &mut rng).unwrap();
    // A head that does not start at zero: every gradient is non-trivial.
    let mut perturbed = Params::new();
    for (name, v) in params.names().iter().zip(params.values()) {
        let v = v.mapv(|x| x + 0.1 * rng.random_range(-1.0f64..1.0));
        perturbed.add(name.clone(), v).unwrap();
    }
    (Nets(a, c), perturbed)
}

/// The viscosities a sample draws from (so a perturbed one is recognised).
const NUS: [f64; 3] = [0.0, 0.02, 0.05];

fn splits(seed: u64, sizes: [usize; 3], steps: usize) -> Splits<Vec<Trajectory>> {
    Splits::generate(DataSeed(seed), sizes, |_, n, rng| {
        Ok((0..n)
            .map(|_| {
                let a = ArrayD::from_shape_fn(vec![1, A], |_| rng.random_range(-1.0..1.0));
                let c = ArrayD::from_shape_fn(vec![1, C], |_| rng.random_range(-1.0..1.0));
                let nu = NUS[rng.random_range(0..NUS.len())];
                let mut s = State::new(
                    vec![a.clone(), c, a.clone()],
                    vec![ArrayD::from_elem(vec![1, A], nu)],
                );
                let mut tr = vec![s.clone()];
                for _ in 0..steps {
                    s = reference(&s);
                    tr.push(s.clone());
                }
                tr
            })
            .collect())
    })
    .unwrap()
}

fn trainer(iterations: usize, evaluations: usize) -> Trainer {
    Trainer {
        budget: Budget {
            iterations,
            evaluations_per_iteration: evaluations,
        },
        learning_rate: 1e-2,
        schedule: LrSchedule::Constant,
        validate_every: 10,
        validation_steps: 8,
    }
}

#[test]
fn the_loss_of_several_fields_has_the_gradient_finite_differences_give() {
    let data = splits(1, [3, 1, 1], 8);
    let (nets, params) = nets(2);
    let hybrid = Hybrid::new(TwoLevel, nets);
    for strategy in [
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
    ] {
        let batch = trainer(1, 12)
            .draw_batch(
                &TwoLevel,
                &strategy,
                &data.train,
                &mut TrainSeed(3).sampling_rng(),
            )
            .unwrap();
        assert_eq!(batch.targets[0].len(), 2, "the physical fields only");
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
        assert!(report.entries > 40, "{strategy}: {}", report.entries);
    }
}

#[test]
fn the_loss_is_the_mean_over_every_entry_of_the_physical_fields() {
    let data = splits(4, [2, 1, 1], 4);
    let (nets, params) = nets(5);
    let hybrid = Hybrid::new(TwoLevel, nets);
    let s0 = State::stack(&[&data.train[0][0], &data.train[1][0]]).unwrap();
    let targets = vec![vec![
        ArrayD::from_elem(s0.fields[0].raw_dim(), 0.25),
        ArrayD::from_elem(s0.fields[1].raw_dim(), -0.5),
    ]];
    let tape = Tape::new();
    let loss = hybrid
        .unrolled_loss(
            &tape,
            &params.bind(&tape),
            &s0.constants(&tape),
            Rc::new(targets.clone()),
            Schedule::Full,
        )
        .unwrap()
        .item()
        .unwrap();
    let next = hybrid.step_plain(Some(&params), &s0).unwrap();
    let mut squares = 0.0;
    let mut entries = 0;
    for (f, t) in next.fields.iter().zip(&targets[0]) {
        squares += (f - t).mapv(|d| d * d).sum();
        entries += f.len();
    }
    let expected = squares / entries as f64;
    assert!(
        (loss - expected).abs() <= 1e-14 * expected,
        "{loss} vs {expected}"
    );
    // The auxiliary is the solver's: the previous a, uncorrected.
    assert_eq!(next.fields[2], s0.fields[0]);
    assert_eq!(next.params, s0.params);
}

#[test]
fn noise_leaves_the_auxiliary_and_the_parameters_alone() {
    let data = splits(6, [4, 1, 1], 6);
    let strategy = Strategy::Noise { sigma: 0.3 };
    let batch = trainer(1, 16)
        .draw_batch(
            &TwoLevel,
            &strategy,
            &data.train,
            &mut TrainSeed(1).sampling_rng(),
        )
        .unwrap();
    let seen = |f: usize| -> HashSet<u64> {
        data.train
            .iter()
            .flatten()
            .flat_map(|s| s.fields[f].iter().map(|x| x.to_bits()).collect::<Vec<_>>())
            .collect()
    };
    let unchanged =
        |a: &ArrayD<f64>, known: &HashSet<u64>| a.iter().all(|x| known.contains(&x.to_bits()));
    assert!(
        unchanged(&batch.start.fields[2], &seen(2)),
        "auxiliary perturbed"
    );
    assert!(
        !unchanged(&batch.start.fields[0], &seen(0)),
        "a not perturbed"
    );
    assert!(
        !unchanged(&batch.start.fields[1], &seen(1)),
        "c not perturbed"
    );
    let nus: HashSet<u64> = NUS.iter().map(|x| x.to_bits()).collect();
    assert!(
        unchanged(&batch.start.params[0], &nus),
        "parameters perturbed"
    );
}

#[test]
fn training_through_several_fields_helps_and_repeats() {
    let data = splits(7, [6, 3, 1], 16);
    let (nets_, _) = nets(0);
    let hybrid = Hybrid::new(TwoLevel, nets_);
    let coarse = rollout(&hybrid, None, &data.validation, 8).unwrap().mean();
    let strategy = Strategy::SolverInTheLoop {
        unroll: 4,
        schedule: Schedule::Every(2),
    };
    let run = || {
        let (_, params) = nets(11);
        trainer(60, 8)
            .train(
                &hybrid,
                params,
                strategy,
                &data.train,
                &data.validation,
                TrainSeed(11),
                &|| {},
            )
            .unwrap()
    };
    let (a, b) = (run(), run());
    assert_eq!(a.model.params.values(), b.model.params.values());
    assert!(
        a.model.validation < 0.75 * coarse,
        "validation {} vs coarse {coarse}",
        a.model.validation
    );
}

/// A corrector that forgets the second physical field.
struct OneNet(UNet);

impl Corrector for OneNet {
    fn correction<'t>(
        &self,
        p: &Bound<'t, f64>,
        s: &StateVars<'t>,
    ) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        Ok(vec![self.0.forward(p, s.fields[0])?])
    }
}

#[test]
fn a_correction_per_physical_field_or_a_typed_error() {
    let data = splits(8, [2, 1, 1], 8);
    let (Nets(a, _), params) = nets(0);
    let hybrid = Hybrid::new(TwoLevel, OneNet(a));
    let result = trainer(5, 8).train(
        &hybrid,
        params,
        Strategy::NonInteracting,
        &data.train,
        &data.validation,
        TrainSeed(1),
        &|| {},
    );
    match result {
        Err(e @ LearnError::CorrectorFields { expected, got }) => {
            assert_eq!((expected, got), (2, 1));
            assert!(e.to_string().contains("2 physical fields"), "{e}");
        }
        other => panic!("expected a corrector-fields error, got {other:?}"),
    }
}
