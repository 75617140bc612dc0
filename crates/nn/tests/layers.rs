//! Every layer against finite differences (f64), its linear part against the
//! dot-product test, and the fused ops against the chains of primitives they
//! replace.

use diffphys_nn::conv::{conv_forward, conv_vjp};
use diffphys_nn::dense::dense_forward;
use diffphys_nn::reference::conv_from_primitives;
use diffphys_nn::resample::{resample_adjoint, resample_forward, Direction};
use diffphys_nn::{
    Activation, Arithmetic, Bound, ConvOp, Layer, Padding, Params, UNet, UNetConfig,
};
use diffphys_tape::{
    check_adjoint, check_gradient, test_array, AdjointReport, ArrayD, ArrayViewD, GradCheckOptions,
    IxDyn, Tape,
};
use rand::SeedableRng;

fn rng() -> rand::rngs::StdRng {
    rand::rngs::StdRng::seed_from_u64(42)
}

fn zeros(shape: &[usize]) -> ArrayD<f64> {
    ArrayD::zeros(IxDyn(shape))
}

fn f64_options() -> GradCheckOptions {
    GradCheckOptions::for_type::<f64>()
}

fn conv_op(padding: Padding, arithmetic: Arithmetic) -> ConvOp {
    ConvOp {
        name: "conv".into(),
        padding,
        arithmetic,
        threads: 1,
    }
}

/// The shapes the convolution's checks run on: 1D, 2D with a 3 × 3 and a 1 × 5
/// kernel (the weight gradient's specialised paths) and with a 3 × 5 kernel
/// (one pass per tap); output channel counts that are not a multiple of the
/// correlation's block of 4, odd ones leaving the weight gradient's pairs a
/// single channel.
fn conv_shapes() -> [(Vec<usize>, Vec<usize>); 4] {
    [
        (vec![2, 2, 7], vec![3, 2, 3]),
        (vec![2, 2, 5, 4], vec![3, 2, 3, 3]),
        (vec![1, 1, 3, 6], vec![2, 1, 1, 5]),
        (vec![1, 2, 4, 6], vec![3, 2, 3, 5]),
    ]
}

/// Every shape of [`conv_shapes`] in both paddings against finite differences.
fn conv_passes_finite_differences(arithmetic: Arithmetic, options: GradCheckOptions) {
    for padding in [Padding::Zero, Padding::Periodic] {
        for (x_shape, w_shape) in conv_shapes() {
            let inputs = [
                test_array::<f64>(&x_shape, 1),
                test_array::<f64>(&w_shape, 2),
                test_array::<f64>(&[w_shape[0]], 3),
            ];
            let report = check_gradient(
                |t, v| t.apply(conv_op(padding, arithmetic), &[v[0], v[1], v[2]]),
                &inputs,
                options,
            )
            .unwrap();
            assert!(
                report.passed,
                "{arithmetic:?} {padding:?} {x_shape:?}: {report:?}"
            );
        }
    }
}

#[test]
fn conv_passes_finite_differences_in_1d_and_2d_for_both_paddings() {
    conv_passes_finite_differences(Arithmetic::Native, f64_options());
}

#[test]
fn conv_is_linear_in_x_and_in_w_with_adjoints_that_pass_the_dot_product_test() {
    for padding in [Padding::Zero, Padding::Periodic] {
        let w = test_array::<f64>(&[3, 2, 3, 5], 4);
        let x = test_array::<f64>(&[2, 2, 6, 7], 5);
        let [in_x, in_w] = conv_adjoints(&x, &w, padding, Arithmetic::Native);
        assert!(in_x.passes(1e-14), "{in_x:?}");
        assert!(in_w.passes(1e-14), "{in_w:?}");
    }
}

/// The dot-product test of the convolution (no bias) in `x` and in `w`, at
/// `x` and `w`, against a test array of the output's shape.
fn conv_adjoints(
    x: &ArrayD<f64>,
    w: &ArrayD<f64>,
    padding: Padding,
    arithmetic: Arithmetic,
) -> [AdjointReport; 2] {
    let zero_bias = ArrayD::zeros(IxDyn(&[w.shape()[0]]));
    let y_shape: Vec<usize> = [x.shape()[0], w.shape()[0]]
        .iter()
        .chain(&x.shape()[2..])
        .copied()
        .collect();
    let y = test_array::<f64>(&y_shape, 6);
    let forward = |x: ArrayViewD<'_, f64>, w: ArrayViewD<'_, f64>| {
        conv_forward("conv", x, w, zero_bias.view(), padding, arithmetic, 1).unwrap()
    };
    let vjp = |g: ArrayViewD<'_, f64>, needs| {
        conv_vjp("conv", x.view(), w.view(), g, padding, needs, arithmetic).unwrap()
    };
    [
        check_adjoint(
            |x| forward(x, w.view()),
            |g| vjp(g, [true, false, false]).0.unwrap(),
            x.view(),
            y.view(),
        )
        .unwrap(),
        check_adjoint(
            |w| forward(x.view(), w),
            |g| vjp(g, [false, true, false]).1.unwrap(),
            w.view(),
            y.view(),
        )
        .unwrap(),
    ]
}

#[test]
fn conv_matches_the_chain_of_primitives_in_value_and_gradient() {
    for padding in [Padding::Zero, Padding::Periodic] {
        for (x_shape, w_shape) in [
            (vec![2, 3, 9], vec![4, 3, 5]),
            (vec![2, 3, 6, 5], vec![4, 3, 3, 3]),
        ] {
            let seed = test_array::<f64>(
                &[2, 4]
                    .iter()
                    .chain(&x_shape[2..])
                    .copied()
                    .collect::<Vec<_>>(),
                9,
            );
            let run = |fused: bool| {
                let tape = Tape::<f64>::new();
                let x = tape.var(test_array(&x_shape, 7));
                let w = tape.var(test_array(&w_shape, 8));
                let b = tape.var(test_array(&[4], 10));
                let y = if fused {
                    tape.apply(conv_op(padding, Arithmetic::Native), &[x, w, b])
                        .unwrap()
                } else {
                    conv_from_primitives(x, w, b, padding).unwrap()
                };
                let value = y.to_array();
                let g = tape
                    .backward_with_seed(y, seed.clone(), &[x, w, b])
                    .unwrap();
                (
                    value,
                    [x, w, b].map(|v| g.get(v).unwrap().clone()),
                    tape.stats(),
                )
            };
            let (vf, gf, sf) = run(true);
            let (vp, gp, sp) = run(false);
            let max_diff = |a: &ArrayD<f64>, b: &ArrayD<f64>| {
                a.iter()
                    .zip(b)
                    .map(|(p, q)| (p - q).abs())
                    .fold(0.0, f64::max)
            };
            assert!(max_diff(&vf, &vp) < 1e-13, "{padding:?} {x_shape:?} values");
            for k in 0..3 {
                assert!(
                    max_diff(&gf[k], &gp[k]) < 1e-12,
                    "{padding:?} {x_shape:?} gradient {k}"
                );
            }
            // The fused op records one node and keeps only its output.
            assert_eq!(sf.nodes, 1);
            assert!(sp.nodes > 3 * w_shape[2]);
            assert!(sf.bytes < sp.bytes);
        }
    }
}

#[test]
fn conv_in_single_arithmetic_passes_finite_differences_with_a_step_its_linearity_allows() {
    // The op is linear in each input, so a central difference is exact at any
    // step: a step of 0.5 keeps f32's rounding (~1e-7 of the output) far below
    // the tolerance, which an f64 step of ~1e-5 would not.
    conv_passes_finite_differences(
        Arithmetic::Single,
        GradCheckOptions {
            rel_tol: 1e-4,
            abs_tol: 1e-6,
            step: Some(0.5),
        },
    );
}

#[test]
fn conv_in_single_arithmetic_passes_the_dot_product_test_and_agrees_with_native_to_f32_rounding() {
    use Arithmetic::{Native, Single};
    for padding in [Padding::Zero, Padding::Periodic] {
        for (x_shape, w_shape) in conv_shapes() {
            let x = test_array::<f64>(&x_shape, 5);
            let w = test_array::<f64>(&w_shape, 4);
            let bias = test_array::<f64>(&[w_shape[0]], 3);
            let y_shape: Vec<usize> = [x_shape[0], w_shape[0]]
                .iter()
                .chain(&x_shape[2..])
                .copied()
                .collect();
            let y = test_array::<f64>(&y_shape, 6);
            let [in_x, in_w] = conv_adjoints(&x, &w, padding, Single);
            assert!(in_x.passes(1e-6), "{padding:?} {x_shape:?}: {in_x:?}");
            assert!(in_w.passes(1e-6), "{padding:?} {x_shape:?}: {in_w:?}");

            // Against the f64 kernel: within f32's rounding, and not equal (the
            // products really ran in f32).
            let relative = |a: &ArrayD<f64>, b: &ArrayD<f64>| {
                let scale = b.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
                a.iter()
                    .zip(b)
                    .fold(0.0_f64, |m, (p, q)| m.max((p - q).abs()))
                    / scale
            };
            let forward = |a| conv_forward("conv", x.view(), w.view(), bias.view(), padding, a, 1);
            let (single, native) = (forward(Single).unwrap(), forward(Native).unwrap());
            let gap = relative(&single, &native);
            assert!(
                gap > 0.0 && gap < 1e-6,
                "{padding:?} {x_shape:?} values: {gap:e}"
            );
            let vjp = |a| conv_vjp("conv", x.view(), w.view(), y.view(), padding, [true; 3], a);
            let (single, native) = (vjp(Single).unwrap(), vjp(Native).unwrap());
            for (k, (s, n)) in [
                (single.0, native.0),
                (single.1, native.1),
                (single.2, native.2),
            ]
            .into_iter()
            .enumerate()
            {
                let gap = relative(&s.unwrap(), &n.unwrap());
                assert!(gap < 1e-6, "{padding:?} {x_shape:?} gradient {k}: {gap:e}");
            }
        }
    }
}

#[test]
fn dense_passes_finite_differences_and_the_dot_product_test() {
    let inputs = [
        test_array::<f64>(&[4, 3], 1),
        test_array::<f64>(&[3, 5], 2),
        test_array::<f64>(&[5], 3),
    ];
    let op = || diffphys_nn::dense::DenseOp {
        name: "dense".into(),
    };
    let report = check_gradient(
        |t, v| t.apply(op(), &[v[0], v[1], v[2]]),
        &inputs,
        f64_options(),
    )
    .unwrap();
    assert!(report.passed, "{report:?}");
    // Linear in x for a zero bias: the adjoint is the backward sweep's grad_x.
    let w = &inputs[1];
    let grad_x = |g: ndarray::ArrayViewD<'_, f64>| {
        let tape = Tape::<f64>::new();
        let x = tape.var(inputs[0].clone());
        let y = tape
            .apply(
                op(),
                &[x, tape.constant(w.clone()), tape.constant(zeros(&[5]))],
            )
            .unwrap();
        tape.backward_with_seed(y, g.to_owned(), &[x])
            .unwrap()
            .get(x)
            .unwrap()
            .clone()
    };
    let report = check_adjoint(
        |x| dense_forward("dense", x, w.view(), zeros(&[5]).view()).unwrap(),
        grad_x,
        inputs[0].view(),
        test_array::<f64>(&[4, 5], 4).view(),
    )
    .unwrap();
    assert!(report.passes(1e-14), "{report:?}");
}

#[test]
fn pooling_and_upsampling_pass_finite_differences_and_the_dot_product_test() {
    for direction in [Direction::Pool, Direction::Upsample] {
        for shape in [vec![2, 3, 8], vec![2, 2, 4, 6]] {
            let op = || diffphys_nn::resample::Resample {
                name: "resample".into(),
                direction,
            };
            let x = test_array::<f64>(&shape, 5);
            let report = check_gradient(
                |t, v| t.apply(op(), &[v[0]]),
                std::slice::from_ref(&x),
                f64_options(),
            )
            .unwrap();
            assert!(report.passed, "{direction:?} {shape:?}: {report:?}");
            let y = resample_forward("resample", direction, x.view()).unwrap();
            let probe = test_array::<f64>(y.shape(), 6);
            let adjoint = check_adjoint(
                |x| resample_forward("resample", direction, x).unwrap(),
                |g| resample_adjoint("resample", direction, g, &shape).unwrap(),
                x.view(),
                probe.view(),
            )
            .unwrap();
            assert!(
                adjoint.passes(1e-14),
                "{direction:?} {shape:?}: {adjoint:?}"
            );
        }
    }
    // Pooling then upsampling a field that is constant on 2×2 blocks gives it back.
    let coarse = test_array::<f64>(&[1, 1, 3, 2], 7);
    let fine = resample_forward("up", Direction::Upsample, coarse.view()).unwrap();
    assert_eq!(fine.shape(), &[1, 1, 6, 4]);
    assert_eq!(
        resample_forward("pool", Direction::Pool, fine.view()).unwrap(),
        coarse
    );
}

/// The adjoint of pooling and upsampling given a gradient of the wrong shape
/// (or an input shape pooling cannot take) is a typed error, not a panic.
#[test]
fn resampling_adjoints_refuse_gradients_of_the_wrong_shape() {
    let x_shape = [1, 2, 4, 6];
    for (direction, right) in [
        (Direction::Pool, [1, 2, 2, 3]),
        (Direction::Upsample, [1, 2, 8, 12]),
    ] {
        let ok = test_array::<f64>(&right, 1);
        assert!(resample_adjoint("r", direction, ok.view(), &x_shape).is_ok());
        for wrong in [vec![1, 2, 4, 6], vec![1, 2, 2], vec![2, 2, 2, 3], vec![]] {
            let g = test_array::<f64>(&wrong, 2);
            let e = resample_adjoint("r", direction, g.view(), &x_shape).unwrap_err();
            assert!(
                e.to_string().contains("r adjoint"),
                "{direction:?} {wrong:?}: {e}"
            );
        }
    }
    let g = test_array::<f64>(&[1, 1, 2, 2], 3);
    let e = resample_adjoint("r", Direction::Pool, g.view(), &[1, 1, 5, 4]).unwrap_err();
    assert!(e.to_string().contains("even"), "{e}");
}

/// A tiny U-Net with a non-zero head, so every parameter gets a gradient.
fn small_unet(dims: usize, padding: Padding) -> (Params<f64>, UNet) {
    let mut params = Params::new();
    let config = UNetConfig {
        dims,
        c_in: 1,
        c_out: 2,
        widths: vec![2, 3],
        kernel: 3,
        padding,
        activation: Activation::Tanh,
    };
    let net = UNet::new(&mut params, "net", config, &mut rng()).unwrap();
    let mut values = params.values().to_vec();
    for (v, name) in values.iter_mut().zip(params.names()) {
        if name.starts_with("net.head") {
            *v = test_array(v.shape(), 11);
        }
    }
    let mut with_head = Params::new();
    for (name, v) in params.names().iter().zip(values) {
        with_head.add(name.clone(), v).unwrap();
    }
    (with_head, net)
}

#[test]
fn unet_passes_finite_differences_in_its_input_and_every_parameter() {
    for (dims, shape, padding) in [
        (1, vec![2, 1, 8], Padding::Periodic),
        (2, vec![1, 1, 4, 4], Padding::Zero),
    ] {
        let (params, net) = small_unet(dims, padding);
        let mut inputs = vec![test_array::<f64>(&shape, 12)];
        inputs.extend(params.values().iter().cloned());
        let report = check_gradient(
            |_, v| net.forward(&Bound::from_vars(v[1..].to_vec()), v[0]),
            &inputs,
            f64_options(),
        );
        let report = report.unwrap();
        assert!(report.passed, "{dims}D: {report:?}");
    }
}
