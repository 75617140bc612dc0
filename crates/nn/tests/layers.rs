//! Every layer against finite differences (f64), its linear part against the
//! dot-product test, and the fused ops against the chains of primitives they
//! replace.

use diffphys_nn::conv::{conv_forward, conv_vjp};
use diffphys_nn::reference::conv_from_primitives;
use diffphys_nn::resample::{resample_adjoint, resample_forward, Direction};
use diffphys_nn::{
    Activation, AvgPool2, Conv1d, Conv2d, ConvConfig, ConvOp, Dense, Init, Layer, Padding, Params,
    UNet, UNetConfig, Upsample2,
};
use diffphys_tape::{
    check_adjoint, check_gradient, test_array, ArrayD, GradCheckOptions, Tape, TapeError,
};
use rand::SeedableRng;

fn rng() -> rand::rngs::StdRng {
    rand::rngs::StdRng::seed_from_u64(42)
}

fn f64_options() -> GradCheckOptions {
    GradCheckOptions::for_type::<f64>()
}

fn conv_op(padding: Padding) -> ConvOp {
    ConvOp {
        name: "conv".into(),
        padding,
    }
}

#[test]
fn conv_passes_finite_differences_in_1d_and_2d_for_both_paddings() {
    for padding in [Padding::Zero, Padding::Periodic] {
        for (x_shape, w_shape) in [
            (vec![2, 2, 7], vec![3, 2, 3]),
            (vec![2, 2, 5, 4], vec![3, 2, 3, 3]),
            (vec![1, 1, 3, 6], vec![2, 1, 1, 5]),
        ] {
            let inputs = [
                test_array::<f64>(&x_shape, 1),
                test_array::<f64>(&w_shape, 2),
                test_array::<f64>(&[w_shape[0]], 3),
            ];
            let report = check_gradient(
                |t, v| t.apply1(conv_op(padding), &[v[0], v[1], v[2]]),
                &inputs,
                f64_options(),
            )
            .unwrap();
            assert!(report.passed, "{padding:?} {x_shape:?}: {report:?}");
        }
    }
}

#[test]
fn conv_is_linear_in_x_and_in_w_with_adjoints_that_pass_the_dot_product_test() {
    for padding in [Padding::Zero, Padding::Periodic] {
        let w = test_array::<f64>(&[3, 2, 3, 5], 4);
        let x = test_array::<f64>(&[2, 2, 6, 7], 5);
        let zero_bias = ArrayD::zeros(ndarray::IxDyn(&[3]));
        let y = test_array::<f64>(&[2, 3, 6, 7], 6);
        let in_x = check_adjoint(
            |x| conv_forward("conv", x, w.view(), zero_bias.view(), padding).unwrap(),
            |g| {
                conv_vjp("conv", x.view(), w.view(), g, padding, [true, false, false])
                    .unwrap()
                    .0
                    .unwrap()
            },
            x.view(),
            y.view(),
        )
        .unwrap();
        assert!(in_x.passes(1e-14), "{in_x:?}");
        let in_w = check_adjoint(
            |w| conv_forward("conv", x.view(), w, zero_bias.view(), padding).unwrap(),
            |g| {
                conv_vjp("conv", x.view(), w.view(), g, padding, [false, true, false])
                    .unwrap()
                    .1
                    .unwrap()
            },
            w.view(),
            y.view(),
        )
        .unwrap();
        assert!(in_w.passes(1e-14), "{in_w:?}");
    }
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
                    tape.apply1(conv_op(padding), &[x, w, b]).unwrap()
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
