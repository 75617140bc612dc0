//! Models as a user meets them: construction, wrong shapes, save and load,
//! deterministic training, and a non-finite loss.

use diffphys_nn::{
    check_loss, stack, Activation, Conv1, Conv2, ConvConfig, Dense, Init, Layer, NnError, Padding,
    Params, UNet, UNetConfig,
};
use diffphys_tape::{test_array, Adam, ArrayD, IxDyn, Tape, TapeError};
use rand::SeedableRng;

fn rng(seed: u64) -> rand::rngs::StdRng {
    rand::rngs::StdRng::seed_from_u64(seed)
}

fn conv_config(c_in: usize, c_out: usize) -> ConvConfig {
    ConvConfig {
        c_in,
        c_out,
        kernel: 3,
        padding: Padding::Zero,
        init: Init::He,
    }
}

fn unet_2d(params: &mut Params<f64>, seed: u64) -> UNet {
    let config = UNetConfig {
        dims: 2,
        c_in: 1,
        c_out: 1,
        widths: vec![4, 6, 8],
        kernel: 3,
        padding: Padding::Zero,
        activation: Activation::Relu,
    };
    UNet::new(params, "unet", config, &mut rng(seed)).unwrap()
}

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("diffphys-nn-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn a_wrong_input_shape_is_an_error_naming_the_layer_and_the_shapes() {
    let mut params = Params::<f64>::new();
    let conv = Conv2::new(&mut params, "enc", conv_config(2, 4), &mut rng(1)).unwrap();
    let dense = Dense::new(&mut params, "fc", 6, 3, Init::Glorot, &mut rng(1)).unwrap();
    let tape = Tape::new();
    let p = params.bind(&tape);
    let x = tape.constant(ArrayD::zeros(IxDyn(&[5, 3, 8, 8])));
    let err = conv.forward(&p, x).unwrap_err();
    let message = err.to_string();
    assert!(matches!(err, TapeError::ShapeMismatch { .. }), "{err:?}");
    assert!(message.contains("conv2d \"enc\""), "{message}");
    assert!(
        message.contains("[5, 2, 8, 8]") && message.contains("[5, 3, 8, 8]"),
        "{message}"
    );
    let err = dense
        .forward(&p, tape.constant(ArrayD::zeros(IxDyn(&[2, 7]))))
        .unwrap_err();
    assert!(err.to_string().contains("dense \"fc\""), "{err}");
    assert!(err.to_string().contains("[2, 7]"), "{err}");
    // A 1D layer given a 2D field, and a 2D U-Net given a size its pooling cannot halve.
    let mut params1 = Params::<f64>::new();
    let conv1 = Conv1::new(&mut params1, "c1", conv_config(1, 1), &mut rng(1)).unwrap();
    let p1 = params1.bind(&tape);
    assert!(conv1
        .forward(&p1, tape.constant(ArrayD::zeros(IxDyn(&[1, 1, 4, 4]))))
        .is_err());
    let mut params2 = Params::<f64>::new();
    let net = unet_2d(&mut params2, 1);
    let p2 = params2.bind(&tape);
    let err = net
        .forward(&p2, tape.constant(ArrayD::zeros(IxDyn(&[1, 1, 6, 6]))))
        .unwrap_err();
    assert!(err.to_string().contains("even"), "{err}");
}

#[test]
fn bad_configurations_are_errors() {
    let mut params = Params::<f64>::new();
    let even = ConvConfig {
        kernel: 4,
        ..conv_config(1, 1)
    };
    assert!(matches!(
        Conv2::new(&mut params, "k4", even, &mut rng(1)),
        Err(NnError::Config { .. })
    ));
    assert!(matches!(
        Dense::new(&mut params, "d", 0, 3, Init::He, &mut rng(1)),
        Err(NnError::Config { .. })
    ));
    Conv2::new(&mut params, "twice", conv_config(1, 1), &mut rng(1)).unwrap();
    assert!(matches!(
        Conv2::new(&mut params, "twice", conv_config(1, 1), &mut rng(1)),
        Err(NnError::DuplicateName { .. })
    ));
}

#[test]
fn initialisation_is_seeded_and_the_parameter_count_adds_up() {
    let (mut a, mut b, mut c) = (Params::new(), Params::new(), Params::new());
    unet_2d(&mut a, 7);
    unet_2d(&mut b, 7);
    unet_2d(&mut c, 8);
    assert_eq!(a, b);
    assert_ne!(a, c);
    // Per conv: c_out·c_in·9 weights + c_out biases; head 1×1: 4 + 1.
    let conv = |i: usize, o: usize| o * i * 9 + o;
    let expected = conv(1, 4) + conv(4, 4) + conv(4, 6) + conv(6, 6) // down
        + conv(6, 8) + conv(8, 8) // bottom
        + conv(6 + 8, 6) + conv(6, 6) + conv(4 + 6, 4) + conv(4, 4) // up
        + 4 + 1;
    assert_eq!(a.count(), expected);
}

#[test]
fn the_unet_sees_the_whole_grid() {
    let mut params = Params::<f64>::new();
    let net = unet_2d(&mut params, 3);
    // Give the zero head weights so the output depends on the input.
    let mut values = params.values().to_vec();
    let head = params
        .names()
        .iter()
        .position(|n| n == "unet.head.weight")
        .unwrap();
    values[head] = test_array(values[head].shape(), 4);
    let tape = Tape::<f64>::new();
    let vars: Vec<_> = values.into_iter().map(|v| tape.constant(v)).collect();
    let bound = diffphys_nn::Bound::from_vars(vars);
    let x = tape.var(test_array(&[1, 1, 16, 16], 5));
    let y = net.forward(&bound, x).unwrap();
    // The output cell in one corner depends on every input cell, the far corner too.
    let mut seed = ArrayD::zeros(IxDyn(&[1, 1, 16, 16]));
    seed[[0, 0, 0, 0]] = 1.0;
    let g = tape.backward_with_seed(y, seed, &[x]).unwrap();
    let g = g.get(x).unwrap();
    assert!(g[[0, 0, 15, 15]] != 0.0);
    assert!(net.receptive_field() >= 16);
}

#[test]
fn save_and_load_round_trip_bit_for_bit() {
    let mut params = Params::<f64>::new();
    unet_2d(&mut params, 9);
    let path = scratch("roundtrip.npz");
    params.save(&path).unwrap();
    let mut other = Params::new();
    unet_2d(&mut other, 10);
    assert_ne!(params, other);
    other.load(&path).unwrap();
    for (a, b) in params.values().iter().zip(other.values()) {
        assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()));
    }
    // f32 too.
    let mut p32 = Params::<f32>::new();
    Dense::new(&mut p32, "fc", 3, 2, Init::Glorot, &mut rng(1)).unwrap();
    let path32 = scratch("f32.npz");
    p32.save(&path32).unwrap();
    let mut q32 = Params::<f32>::new();
    Dense::new(&mut q32, "fc", 3, 2, Init::Glorot, &mut rng(2)).unwrap();
    q32.load(&path32).unwrap();
    assert_eq!(p32, q32);
}

#[test]
fn loading_a_file_that_does_not_fit_is_an_error_and_changes_nothing() {
    let mut params = Params::<f64>::new();
    Dense::new(&mut params, "fc", 3, 2, Init::Glorot, &mut rng(1)).unwrap();
    let before = params.clone();

    let mut renamed = Params::<f64>::new();
    Dense::new(&mut renamed, "other", 3, 2, Init::Glorot, &mut rng(2)).unwrap();
    let path = scratch("renamed.npz");
    renamed.save(&path).unwrap();
    let err = params.load(&path).unwrap_err();
    assert!(matches!(err, NnError::Mismatch { .. }), "{err:?}");
    assert!(err.to_string().contains("fc.weight"), "{err}");
    assert_eq!(params, before);

    let mut reshaped = Params::<f64>::new();
    Dense::new(&mut reshaped, "fc", 4, 2, Init::Glorot, &mut rng(2)).unwrap();
    let path = scratch("reshaped.npz");
    reshaped.save(&path).unwrap();
    let err = params.load(&path).unwrap_err();
    assert!(
        err.to_string().contains("[4, 2]") && err.to_string().contains("[3, 2]"),
        "{err}"
    );
    assert_eq!(params, before);

    let err = params.load(scratch("missing.npz")).unwrap_err();
    assert!(matches!(err, NnError::File { .. }), "{err:?}");
    assert_eq!(params, before);
}

#[test]
fn non_finite_parameters_are_never_saved() {
    let mut params = Params::<f64>::new();
    let mut w = ArrayD::zeros(IxDyn(&[2]));
    w[[1]] = f64::NAN;
    params.add("w", w).unwrap();
    let path = scratch("nan.npz");
    let err = params.save(&path).unwrap_err();
    assert!(
        matches!(err, NnError::NonFiniteParameter { count: 1, .. }),
        "{err:?}"
    );
    assert!(!path.exists());
}

/// Fits a 1D conv net to a fixed map for `steps` Adam steps; returns the losses.
fn train(seed: u64, steps: usize, lr: f64) -> diffphys_nn::Result<Vec<f64>> {
    let mut r = rng(seed);
    let mut params = Params::<f64>::new();
    let periodic = |c_in, c_out| ConvConfig {
        padding: Padding::Periodic,
        ..conv_config(c_in, c_out)
    };
    let c1 = Conv1::new(&mut params, "c1", periodic(1, 8), &mut r)?;
    let c2 = Conv1::new(&mut params, "c2", periodic(8, 1), &mut r)?;
    let samples: Vec<ArrayD<f64>> = (0..4).map(|k| test_array(&[1, 16], 100 + k)).collect();
    let x = stack(&samples.iter().collect::<Vec<_>>())?;
    let target = x.mapv(|v| v * v - 0.3);
    let mut adam = Adam::new(lr);
    let mut losses = Vec::new();
    for step in 0..steps {
        let tape = Tape::new();
        let p = params.bind(&tape);
        let h = Activation::Relu.apply(c1.forward(&p, tape.constant(x.clone()))?)?;
        let y = c2.forward(&p, h)?;
        let loss = y.sub(tape.constant(target.clone()))?.powi(2)?.mean()?;
        losses.push(check_loss(step, loss.item()?)?);
        let grads = tape.backward(loss, p.vars())?;
        params.step(&mut adam, &grads, &p)?;
    }
    Ok(losses)
}

#[test]
fn training_is_bit_identical_for_a_seed_and_learns() {
    let a = train(5, 60, 1e-2).unwrap();
    let b = train(5, 60, 1e-2).unwrap();
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
    assert!(a[59] < 0.2 * a[0], "{} → {}", a[0], a[59]);
    let c = train(6, 60, 1e-2).unwrap();
    assert_ne!(a, c);
}

#[test]
fn a_non_finite_loss_stops_training_naming_the_step() {
    // A learning rate so large that the loss overflows.
    match train(5, 200, 1e150) {
        Err(NnError::NonFiniteLoss { step, .. }) => assert!(step > 0),
        Err(NnError::Tape(TapeError::NonFinite { .. })) => {}
        other => panic!("expected a non-finite loss error, got {other:?}"),
    }
    assert!(matches!(
        check_loss(3, f64::NAN),
        Err(NnError::NonFiniteLoss { step: 3, .. })
    ));
}

#[test]
fn layers_run_in_f32() {
    let mut params = Params::<f32>::new();
    let config = UNetConfig {
        dims: 1,
        c_in: 1,
        c_out: 1,
        widths: vec![2, 2],
        kernel: 3,
        padding: Padding::Periodic,
        activation: Activation::Tanh,
    };
    let net = UNet::new(&mut params, "u", config, &mut rng(1)).unwrap();
    let tape = Tape::<f32>::new();
    let p = params.bind(&tape);
    let y = net
        .forward(&p, tape.constant(test_array(&[2, 1, 8], 1)))
        .unwrap();
    assert_eq!(y.shape(), vec![2, 1, 8]);
    let loss = y.powi(2).unwrap().sum().unwrap();
    assert!(tape.backward(loss, p.vars()).is_ok());
}
