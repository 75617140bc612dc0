//! The study layer on the tiny scene: typed variants, a study's training
//! against the library's trainer, its log and its learning-rate pilots.

mod common;

use common::*;
use diffphys_learn::study::{Log, OneSize, TrainJob, Trainings, Variant};
use diffphys_learn::*;

#[test]
fn every_variant_steps_whole_windows_of_at_least_the_asked_evaluations() {
    for (variant, expected) in [
        (Variant::Non, 4),
        (Variant::Noise, 4),
        (Variant::Sol(1), 4),
        (Variant::Sol(2), 4),
        (Variant::Sol(3), 6),
        (Variant::Sol(4), 4),
        (Variant::Sol(5), 5),
        (Variant::Sol(16), 16),
    ] {
        let e = variant.step_evaluations(4);
        assert_eq!(e, expected, "{}", variant.name());
        if let Variant::Sol(k) = variant {
            assert_eq!(e % k, 0, "{}: a step holds whole windows", variant.name());
        }
        assert!(e >= 4);
    }
}

#[test]
fn a_budget_becomes_adam_steps_and_zero_stays_zero() {
    assert_eq!(Variant::Sol(4).adam_steps(24_000, 4), 6_000);
    assert_eq!(Variant::Non.adam_steps(24_000, 4), 6_000);
    assert_eq!(Variant::Sol(16).adam_steps(24_000, 4), 1_500);
    // A budget smaller than one step still trains one step; none trains none
    // (the trainer refuses 0 iterations with a typed error).
    assert_eq!(Variant::Sol(16).adam_steps(4, 4), 1);
    assert_eq!(Variant::Sol(4).adam_steps(0, 4), 0);
}

#[test]
fn variants_parse_by_name_and_refuse_the_unknown_and_sol0() {
    for (text, v) in [
        ("src", Variant::Src),
        ("non", Variant::Non),
        ("noise", Variant::Noise),
        ("sol4", Variant::Sol(4)),
        ("sol_16", Variant::Sol(16)),
        ("sol-2", Variant::Sol(2)),
    ] {
        assert_eq!(text.parse::<Variant>().unwrap(), v);
        assert_eq!(
            v.name().parse::<Variant>().unwrap(),
            v,
            "the name parses back"
        );
    }
    assert!(
        matches!("magic".parse::<Variant>(), Err(LearnError::UnknownVariant { name }) if name == "magic")
    );
    assert!(matches!(
        "sol0".parse::<Variant>(),
        Err(LearnError::ZeroUnroll { .. })
    ));
    assert_eq!(Variant::Src.strategy(0.1, Some(4)), None);
    assert_eq!(
        Variant::Sol(16).strategy(0.1, Some(4)).unwrap().schedule(),
        diffphys_learn::Schedule::Every(4)
    );
    assert_eq!(
        Variant::Sol(4).strategy(0.1, Some(4)).unwrap().schedule(),
        diffphys_learn::Schedule::Full
    );
    assert_eq!(Variant::Noise.strategy(0.1, None).unwrap().sigma(), 0.1);
    assert_eq!(
        (
            Variant::Noise.family(),
            Variant::Sol(8).family(),
            Variant::Src.family()
        ),
        (Some("non"), Some("sol"), None)
    );
}

/// A study's training is the library's `Trainer` with the budget shared into
/// whole windows (80 evaluations of `sol_4`: 20 steps of one window,
/// validated every 40 evaluations, checkpointed every 2 steps): the same
/// losses to the bit. Its log keeps the validation score, the per-condition
/// errors and the curve; the pilots keep each family's best rate.
#[test]
fn a_study_training_is_the_trainer_and_its_log_and_pilots_record_it() {
    let s = splits(7, [4, 2, 2], 8);
    let new_net = |_: OneSize, seed: TrainSeed| Ok::<_, LearnError>(net(seed.0, 1));
    let trainings = Trainings {
        simulator: &Cubic,
        corrector: &new_net,
        schedule: LrSchedule::Exponential {
            final_fraction: 0.1,
        },
        step_evaluations: 4,
        checkpoint: Some(2),
        validation_steps: 8,
        validation_evaluations: 40,
        sigma: 0.05,
        train: &s.train,
        validation: &s.validation,
        label: "test".into(),
    };
    let job = TrainJob {
        variant: Variant::Sol(4),
        size: OneSize,
        seed: TrainSeed(3),
        lr: 1e-2,
        evaluations: 80,
    };
    let run = trainings.train(&job).unwrap();
    let (n, p) = net(3, 1);
    let direct = trainer(20, 4)
        .train(
            &Hybrid::new(Cubic, n),
            p,
            Strategy::SolverInTheLoop {
                unroll: 4,
                schedule: Schedule::Every(2),
            },
            &s.train,
            &s.validation,
            TrainSeed(3),
            &|| {},
        )
        .unwrap();
    assert_eq!(run.trained.model.losses, direct.model.losses);
    assert_eq!(run.trained.model.losses.len(), 20);
    assert_eq!(run.trained.model.validation, direct.model.validation);
    assert_eq!(run.validation_per_condition.len(), s.validation.len());
    assert!(matches!(
        trainings.train(&TrainJob {
            variant: Variant::Src,
            ..job
        }),
        Err(LearnError::Invalid { .. })
    ));

    let mut log = Log::default();
    log.training(1, &run, OneSize, &["a".into(), "b".into()]);
    let j = log.to_json("case");
    assert_eq!(j["validation_rel_error"]["sol_4"]["runs"], 1);
    assert_eq!(
        j["validation_per_case"]["sol_4"]["a"]["mean"],
        run.validation_per_condition[0]
    );
    assert_eq!(
        j["validation_curves"]["sol_4_data_1_seed_3"]["kept_iteration"],
        run.trained.model.best_iteration
    );

    let lrs = trainings
        .learning_rates(
            &[Variant::Src, Variant::Sol(4), Variant::Noise, Variant::Non],
            &[1e-3, 3e-2],
            (OneSize, TrainSeed(3), 40),
            2,
        )
        .unwrap();
    let families: Vec<&str> = lrs.pilots.scores.iter().map(|(f, _)| *f).collect();
    assert_eq!(families, ["non", "sol"]);
    for (family, scores) in &lrs.pilots.scores {
        let best = scores.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap().0;
        assert_eq!(lrs.pilots.rate(family), Some(best));
    }
    assert_eq!(lrs.of(Variant::Noise), lrs.of(Variant::Non));
    assert_eq!(lrs.of(Variant::Sol(16)), lrs.pilots.rate("sol").unwrap());
}
