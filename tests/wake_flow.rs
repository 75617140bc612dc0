//! The wake-flow scene (examples/wake_flow.rs) refuses bad input with typed
//! errors: an unknown variant, an unroll of 0, a Reynolds number outside the
//! stated range, an empty split, a corrector whose output does not match the
//! state; and its noise leaves the state's viscosity and fixed faces alone.
//! The inscribed and staircase bodies leave no flow on the faces the coarse
//! solver pins; the cylinder body does.

#[allow(dead_code, unused_imports)] // the test uses a part of the scene
#[path = "../examples/wake_flow_scene/mod.rs"]
mod wake_flow_scene;

use clap::Parser;
use diffphys::flow::{FlowState, PressureSolver, Splitting};
use diffphys::hybrid::wake::args::{seeds, Cli, Command};
use diffphys::hybrid::{free_faces, sample, HybridError, LatticeNet};
use diffphys::hybrid::{FlowSimulator as Coarse, NetSize};
use diffphys::learn::{Hybrid, LearnError, Simulator, Split, State, TrainSeed};
use diffphys::nn::Arithmetic;
use ndarray::Array2;
use wake_flow_scene::{re_code, small_sizes, Options, Sizes, Variant, Wake, CHANNEL};

/// The scene's corrector of `size` on the coarse scene `c`.
fn net(c: &Coarse, size: NetSize) -> (LatticeNet, diffphys::nn::Params<f64>) {
    let rng = &mut TrainSeed(1).init_rng();
    LatticeNet::new(c.scene(), size, re_code, Arithmetic::Single, rng).unwrap()
}

/// The scene at `sizes`.
fn wake(sizes: Sizes) -> Wake {
    Wake {
        channel: CHANNEL,
        sizes,
    }
}

/// The coarse solver of `sizes`.
fn uncorrected(sizes: Sizes) -> diffphys::flow::Scene {
    wake(sizes)
        .uncorrected(1, PressureSolver::Cholesky)
        .unwrap()
}

/// The command line `wake_flow --small ARGS`, parsed by clap (which must
/// accept it) and made typed options by the scene.
fn cli(args: &[&str]) -> Cli {
    let line = ["wake_flow", "--small"].iter().chain(args);
    Cli::try_parse_from(line).expect("clap accepts the flags")
}

fn options(args: &[&str]) -> Result<Options, HybridError> {
    wake_flow_scene::options(&cli(args).train)
}

#[test]
fn options_parse_with_the_small_defaults() {
    let o = options(&["--variants", "non,sol8", "--held-out-re", "300,3000"]).unwrap();
    assert_eq!(
        o.variants,
        vec![Variant::Src, Variant::Non, Variant::Sol(8)]
    );
    assert_eq!(o.held_out_re, vec![300.0, 3000.0]);
    assert_eq!(o.train_re, vec![200.0, 400.0, 800.0]);
    assert!(!o.inside(3000.0));
    let (data, train) = seeds(&cli(&["--train-seeds", "4,5"]).train).unwrap();
    assert_eq!((data, train), (vec![1], vec![4, 5]));
    assert!(matches!(
        seeds(&cli(&["--train-seeds", "4,x"]).train),
        Err(HybridError::Argument { .. })
    ));
    assert!(matches!(
        options(&["--lrs", "1e-3,-1"]),
        Err(HybridError::Argument { .. })
    ));
}

#[test]
fn an_unknown_flag_and_evaluate_without_a_model_are_usage_errors() {
    assert!(Cli::try_parse_from(["wake_flow", "--magic"]).is_err());
    assert!(Cli::try_parse_from(["wake_flow", "evaluate", "--small"]).is_err());
    let c = Cli::try_parse_from([
        "wake_flow",
        "evaluate",
        "--model",
        "m",
        "--body",
        "staircase",
    ])
    .unwrap();
    match c.command {
        Some(Command::Evaluate(e)) => {
            assert_eq!(e.model, std::path::PathBuf::from("m"));
            assert_eq!(
                wake_flow_scene::scene_options(&e.scene).unwrap().body,
                wake_flow_scene::Body::Staircase
            );
        }
        _ => panic!("evaluate parses as the subcommand"),
    }
    let c =
        Cli::try_parse_from(["wake_flow", "convergence", "--small", "--data-seed", "4"]).unwrap();
    match c.command {
        Some(Command::Convergence(c)) => assert_eq!((c.data_seed, c.scene.small), (4, true)),
        _ => panic!("convergence parses as the subcommand"),
    }
    assert!(Cli::try_parse_from(["wake_flow", "convergence", "--data-seed", "x"]).is_err());
}

#[test]
fn an_unknown_variant_is_refused() {
    match options(&["--variants", "non,magic"]) {
        Err(HybridError::Learn(LearnError::UnknownVariant { name })) => assert_eq!(name, "magic"),
        other => panic!("expected an unknown variant, got {other:?}"),
    }
}

#[test]
fn an_unroll_of_zero_is_refused() {
    assert!(matches!(
        options(&["--variants", "sol0"]),
        Err(HybridError::Learn(LearnError::ZeroUnroll { .. }))
    ));
}

#[test]
fn a_reynolds_number_outside_the_range_is_refused() {
    for re in ["10", "5000", "nan"] {
        match options(&["--held-out-re", re]) {
            Err(HybridError::ReOutOfRange { .. }) => {}
            other => panic!("Re {re}: expected out of range, got {other:?}"),
        }
    }
    assert!(matches!(
        options(&["--held-out-re", "abc"]),
        Err(HybridError::Argument { .. })
    ));
}

#[test]
fn an_empty_split_is_refused() {
    for (flag, split) in [
        ("--train-re", Split::Train),
        ("--validation-re", Split::Validation),
        ("--held-out-re", Split::HeldOut),
    ] {
        match options(&[flag, ","]) {
            Err(HybridError::Learn(LearnError::EmptySplit { split: s, .. })) => {
                assert_eq!(s, split)
            }
            other => panic!("{flag}: expected an empty split, got {other:?}"),
        }
    }
}

fn coarse() -> Coarse {
    Coarse::new(uncorrected(small_sizes()))
}

/// A batch of one uniform flow at Re 400.
fn probe(c: &Coarse) -> State {
    let g = c.scene().grid();
    let s = FlowState::from_velocity(
        c.scene(),
        Array2::from_elem(g.shape_x(), 1.0),
        Array2::zeros(g.shape_y()),
    );
    State::stack(&[&sample(c.scene(), &s, CHANNEL.viscosity(400.0))]).unwrap()
}

#[test]
fn a_corrector_of_the_wrong_shape_is_refused() {
    let c = coarse();
    let size = NetSize {
        width: 4,
        blocks: 1,
    };
    let (net3, params) = LatticeNet::with_outputs(
        c.scene(),
        size,
        re_code,
        3,
        Arithmetic::Single,
        &mut TrainSeed(1).init_rng(),
    )
    .unwrap();
    let hybrid = Hybrid::new(c.clone(), net3);
    match hybrid.check_shapes(&params, &probe(&c)) {
        Err(LearnError::CorrectorFields { expected, got }) => {
            assert_eq!((expected, got), (2, 3));
        }
        other => panic!("expected a corrector-fields error, got {other:?}"),
    }
    let (corrector, params) = net(&c, size);
    Hybrid::new(c.clone(), corrector)
        .check_shapes(&params, &probe(&c))
        .unwrap();
}

#[test]
fn the_incremental_coarse_solver_carries_its_pressure_uncorrected() {
    let o = options(&["--coarse-splitting", "incremental"]).unwrap();
    assert_eq!(o.coarse_splitting, Splitting::Incremental);
    assert!(matches!(
        options(&["--coarse-splitting", "strang"]),
        Err(HybridError::Argument { .. })
    ));
    let c = Coarse::new(uncorrected(wake_flow_scene::wake(&o, true).sizes));
    assert_eq!(c.auxiliary_fields(), 1);
    let probe = probe(&c);
    assert_eq!(probe.fields.len(), 3);
    let size = NetSize {
        width: 4,
        blocks: 1,
    };
    let (corrector, zero_head) = net(&c, size);
    // A head that does not start at zero, so the correction is not nothing.
    let mut params = diffphys::nn::Params::new();
    for (name, v) in zero_head.names().iter().zip(zero_head.values()) {
        params.add(name.clone(), v.mapv(|x| x + 0.01)).unwrap();
    }
    let hybrid = Hybrid::new(c, corrector);
    hybrid.check_shapes(&params, &probe).unwrap();
    let corrected = hybrid.step_plain(Some(&params), &probe).unwrap();
    let solver = hybrid.step_plain(None, &probe).unwrap();
    assert_ne!(corrected.fields[0], solver.fields[0], "u_x not corrected");
    assert_eq!(
        corrected.fields[2], solver.fields[2],
        "the pressure corrected"
    );
    assert!(
        solver.fields[2].iter().any(|p| *p != 0.0),
        "no pressure carried"
    );
}

#[test]
fn noise_leaves_the_viscosity_and_the_fixed_faces_alone() {
    let c = coarse();
    let clean = probe(&c);
    let mut noisy = clean.clone();
    c.perturb(&mut noisy, 0.1, &mut TrainSeed(2).sampling_rng());
    assert_eq!(noisy.params, clean.params, "the viscosity moved");
    let free = free_faces(c.scene());
    let mut moved = 0;
    for (channel, (n, m)) in noisy.fields.iter().zip(&clean.fields).enumerate() {
        for ((i, &x), &y) in n.indexed_iter().zip(m.iter()) {
            if free[[channel, i[1], i[2]]] == 0.0 {
                assert_eq!(x, y, "fixed face {channel} {i:?} moved");
            } else if x != y {
                moved += 1;
            }
        }
    }
    assert!(moved as f64 > 0.9 * free.sum());
    // The inflow face and the padding are fixed.
    let b = free.shape()[2];
    assert_eq!(free[[0, 0, 3]], 0.0);
    assert_eq!(free[[0, 3, b - 1]], 0.0);
}

#[test]
fn capacity_sizes_parse_and_bad_ones_are_refused() {
    let o = options(&["--capacity-sizes", "w8b1,w16b2,w32b3"]).unwrap();
    // The main size is always trained; the sweep lists the others.
    assert_eq!(
        o.capacity,
        vec![
            NetSize {
                width: 8,
                blocks: 1
            },
            NetSize {
                width: 32,
                blocks: 3
            }
        ]
    );
    for bad in ["w0b1", "8b1", "wxb2"] {
        assert!(matches!(
            options(&["--capacity-sizes", bad]),
            Err(HybridError::Argument { .. })
        ));
    }
    assert!(options(&["--no-capacity"]).unwrap().capacity.is_empty());
}

#[test]
fn the_coarse_advection_parses_and_an_unknown_one_is_refused() {
    use diffphys::flow::Advection;
    assert_eq!(
        options(&[]).unwrap().coarse_advection,
        Advection::SemiLagrangian
    );
    let o = options(&["--coarse-advection", "maccormack"]).unwrap();
    assert_eq!(o.coarse_advection, Advection::MacCormack { limiter: true });
    let scene = uncorrected(Sizes {
        advection: o.coarse_advection,
        ..small_sizes()
    });
    assert_eq!(
        scene.settings().advection,
        Advection::MacCormack { limiter: true }
    );
    match options(&["--coarse-advection", "upwind"]) {
        Err(HybridError::Argument { option, message }) => {
            assert_eq!(option, "--coarse-advection");
            assert!(message.contains("upwind"), "{message}");
        }
        other => panic!("expected an argument error, got {other:?}"),
    }
}

#[test]
fn the_body_the_reference_scheme_and_the_arithmetic_parse_and_unknown_names_are_refused() {
    use wake_flow_scene::{Body, ReferenceScheme};
    let o = options(&[]).unwrap();
    assert_eq!(o.body, Body::Inscribed);
    assert_eq!(o.reference, ReferenceScheme::SecondOrder);
    let o = options(&["--body", "cylinder", "--reference-scheme", "coarse"]).unwrap();
    assert_eq!(o.body, Body::Cylinder);
    assert_eq!(o.reference, ReferenceScheme::Coarse);
    assert_eq!(
        options(&["--body", "staircase"]).unwrap().body,
        Body::Staircase
    );
    assert_eq!(o.arithmetic, Arithmetic::Single);
    let o = options(&["--network-arithmetic", "f64"]).unwrap();
    assert_eq!(o.arithmetic, Arithmetic::Native);
    for (flag, bad) in [
        ("--body", "round"),
        ("--reference-scheme", "spectral"),
        ("--network-arithmetic", "bf16"),
    ] {
        match options(&[flag, bad]) {
            Err(HybridError::Argument { option, message }) => {
                assert_eq!(option, flag);
                assert!(message.contains(bad), "{message}");
            }
            other => panic!("expected an argument error, got {other:?}"),
        }
    }
}

/// The pinned-face error of the restricted state after one reference step
/// from uniform flow: the reference pins its solid faces, the restriction
/// averages them onto the coarse grid.
fn pinned_after_one_reference_step(body: wake_flow_scene::Body) -> f64 {
    use diffphys::flow::restrict_velocity;
    let w = wake(Sizes {
        body,
        ..small_sizes()
    });
    let coarse = Coarse::new(w.uncorrected(1, PressureSolver::Cholesky).unwrap());
    let fine = w.reference_scene().unwrap();
    let mut start = FlowState::zeros(&fine);
    start.ux.fill(1.0);
    let after = fine.forward(&start, &fine.params()).unwrap().0;
    let (ux, uy) = restrict_velocity(
        coarse.scene().grid(),
        CHANNEL.factor,
        after.ux.view(),
        after.uy.view(),
    )
    .unwrap();
    let state = sample(
        coarse.scene(),
        &FlowState::from_velocity(coarse.scene(), ux, uy),
        fine.params().viscosity,
    );
    coarse.pinned_face_error(&[state.clone(), state]).unwrap()
}

#[test]
fn only_the_cylinder_body_leaves_flow_on_the_pinned_faces() {
    use wake_flow_scene::Body;
    let cylinder = pinned_after_one_reference_step(Body::Cylinder);
    assert!(
        cylinder > 1e-3,
        "cylinder body: pinned-face error {cylinder}"
    );
    for body in [Body::Staircase, Body::Inscribed] {
        let e = pinned_after_one_reference_step(body);
        assert_eq!(e, 0.0, "{body:?}: pinned-face error {e}");
    }
}

#[test]
fn the_inscribed_body_is_inside_the_reference_body() {
    use wake_flow_scene::Body;
    const FACTOR: usize = CHANNEL.factor;
    let w = wake(Sizes {
        body: Body::Inscribed,
        ..small_sizes()
    });
    let coarse = w.uncorrected(1, PressureSolver::Cholesky).unwrap();
    let fine = w.reference_scene().unwrap();
    let (c, f) = (coarse.solid(), fine.solid());
    assert!(c.iter().any(|&s| s), "the coarse body has solid cells");
    for ((i, j), &solid) in c.indexed_iter() {
        let all = (0..FACTOR).all(|a| (0..FACTOR).all(|b| f[[FACTOR * i + a, FACTOR * j + b]]));
        assert_eq!(solid, all, "coarse cell ({i}, {j})");
    }
}

/// A finer reference (`--reference-factor 8`) leaves the coarse solver's
/// inscribed body as it was at 4× and sees the cylinder itself; a factor
/// that is not 2, 4, 8 or 16 is refused.
#[test]
fn a_finer_reference_keeps_the_coarse_body() {
    use wake_flow_scene::Body;
    assert_eq!(options(&[]).unwrap().reference_factor, CHANNEL.factor);
    let o = options(&["--reference-factor", "8"]).unwrap();
    assert_eq!(o.reference_factor, 8);
    let refined = wake_flow_scene::wake(&o, true);
    assert_eq!(refined.channel.factor, 8);
    let four = wake(Sizes {
        body: Body::Inscribed,
        ..small_sizes()
    });
    let coarse =
        |w: &Wake| (w.uncorrected(1, PressureSolver::Cholesky).unwrap().solid()).to_owned();
    assert_eq!(coarse(&refined), coarse(&four));
    let fine = refined.reference_scene().unwrap();
    assert_eq!(fine.grid().nx, 8 * small_sizes().nx);
    let cylinder = diffphys::flow::Scene::builder(fine.grid().nx, fine.grid().ny, CHANNEL.extent)
        .obstacle(diffphys::flow::Obstacle::cylinder(
            CHANNEL.centre,
            CHANNEL.diameter / 2.0,
        ))
        .build()
        .unwrap();
    assert_eq!(fine.solid(), cylinder.solid());
    for bad in ["3", "1", "32", "0"] {
        assert!(options(&["--reference-factor", bad]).is_err(), "{bad}");
    }
}

/// `wake_flow evaluate` refuses a saved corrector whose settings do not fit
/// the scene it is asked to run in, naming the field, before it generates any
/// reference.
#[test]
fn evaluate_refuses_a_model_saved_for_another_scene() {
    use diffphys::hybrid::wake::Evaluation;
    use diffphys::learn::SavedModel;
    use wake_flow_scene::{full_sizes, Body, MAIN_SIZE};

    let sizes = small_sizes();
    let c = coarse();
    let (_, params) = net(&c, MAIN_SIZE);
    let dir = std::env::temp_dir().join(format!("diffphys-wake-model-{}", std::process::id()));
    let card = wake(sizes.clone()).card(MAIN_SIZE, Arithmetic::Single);
    SavedModel::save(&dir, &params, &card).unwrap();
    let staircase = Sizes {
        body: Body::Staircase,
        ..small_sizes()
    };
    let full = full_sizes();
    for (scene, arithmetic, field) in [
        (&staircase, Arithmetic::Single, "body"),
        (&sizes, Arithmetic::Native, "network_arithmetic"),
        (&full, Arithmetic::Single, "dt_coarse"),
    ] {
        let asked = Evaluation {
            model: &dir,
            code: re_code,
            arithmetic,
            re: &[283.0],
            data_seed: None,
            out: &dir.join("out"),
            threads: 1,
        };
        match wake(scene.clone()).evaluate(&asked) {
            Err(HybridError::Learn(LearnError::SettingsMismatch { field: f, .. })) => {
                assert_eq!(f, field)
            }
            other => panic!(
                "expected a mismatch on {field}, got {:?}",
                other.map(|_| ())
            ),
        }
    }
    assert!(
        !dir.join("out").exists(),
        "nothing was generated for a refused model"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn validation_only_is_a_flag_of_the_study_not_of_its_configuration() {
    let c = cli(&["--validation-only"]);
    assert!(c.train.validation_only);
    assert!(!cli(&[]).train.validation_only);
    // The options that shape the models (the ledger's configuration) do not
    // change with it: a later full run counts as the same configuration.
    assert_eq!(
        wake_flow_scene::options(&c.train).unwrap(),
        wake_flow_scene::options(&cli(&[]).train).unwrap()
    );
}
