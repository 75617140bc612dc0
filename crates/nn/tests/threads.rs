//! The convolution's forward pass split over threads against the same pass on
//! one thread: equal bit for bit, in `f32` and `f64` arithmetic, at batch 1
//! and 3, on fields whose flat cells do not split evenly; zero threads is an
//! error.

use diffphys_nn::conv::conv_forward;
use diffphys_nn::{Arithmetic, Conv2, ConvConfig, ConvOp, Init, Layer, NnError, Padding, Params};
use diffphys_tape::{test_array, ArrayD, Real, Tape, TapeError};
use rand::SeedableRng;

const THREADS: [usize; 4] = [1, 2, 3, 7];

/// Input and kernel shapes without the batch. The correlation splits a batch
/// element's padded flat cells (rounded up to 32) in blocks of 32 (`f32`) or
/// 16 (`f64`) cells:
/// - 13 × 11, 3 × 3: 192 cells, 6 or 12 blocks (7 threads: 7 runs of 2 or 1
///   blocks in `f64`); 5 output channels, one past the block of 4;
/// - 9 × 17, 3 × 5: 192 cells, the kernel wider than tall;
/// - 101 cells in 1D, kernel 5: 128 cells, 4 or 8 blocks (3 threads: 2, 1, 1
///   or 3, 3, 2);
/// - 33 × 65 (the wake corrector's face lattice at 32 × 64), 3 × 3: 2240
///   cells, 70 or 140 blocks (3 threads: 24, 23, 23 in `f32`); 1 × 1 kernel
///   to 2 channels (its head).
fn shapes() -> [(Vec<usize>, Vec<usize>); 5] {
    [
        (vec![3, 13, 11], vec![5, 3, 3, 3]),
        (vec![2, 9, 17], vec![4, 2, 3, 5]),
        (vec![3, 101], vec![6, 3, 5]),
        (vec![2, 33, 65], vec![5, 2, 3, 3]),
        (vec![3, 33, 65], vec![2, 3, 1, 1]),
    ]
}

fn bits<T: Real>(a: &ArrayD<T>) -> Vec<u64> {
    a.iter().map(|v| v.as_f64().to_bits()).collect()
}

/// Every shape at batch 1 and 3, both paddings: the forward pass on each of
/// [`THREADS`] against one thread, in `arithmetic` on a `T` tape.
fn threaded_forward_is_bit_identical<T: Real>(arithmetic: Arithmetic) {
    for batch in [1, 3] {
        for (k, (x_shape, w_shape)) in shapes().into_iter().enumerate() {
            let x_shape: Vec<usize> = std::iter::once(batch).chain(x_shape).collect();
            let seed = 10 * k as u64;
            let x = test_array::<T>(&x_shape, seed + 1);
            let w = test_array::<T>(&w_shape, seed + 2);
            let bias = test_array::<T>(&[w_shape[0]], seed + 3);
            for padding in [Padding::Zero, Padding::Periodic] {
                let forward = |threads| {
                    let (x, w, b) = (x.view(), w.view(), bias.view());
                    conv_forward("conv", x, w, b, padding, arithmetic, threads).unwrap()
                };
                let one = forward(1);
                for threads in THREADS {
                    assert_eq!(
                        bits(&forward(threads)),
                        bits(&one),
                        "{} {arithmetic:?} {padding:?} {x_shape:?} * {w_shape:?}, {threads} threads",
                        T::NAME
                    );
                }
            }
        }
    }
}

#[test]
fn threaded_forward_equals_one_thread_bit_for_bit_in_f64() {
    threaded_forward_is_bit_identical::<f64>(Arithmetic::Native);
}

#[test]
fn threaded_forward_equals_one_thread_bit_for_bit_in_f32_on_an_f64_tape() {
    threaded_forward_is_bit_identical::<f64>(Arithmetic::Single);
}

#[test]
fn threaded_forward_equals_one_thread_bit_for_bit_on_an_f32_tape() {
    threaded_forward_is_bit_identical::<f32>(Arithmetic::Native);
}

#[test]
fn a_threaded_layer_records_the_same_values_and_gradients() {
    let config = ConvConfig {
        c_in: 3,
        c_out: 5,
        kernel: 3,
        padding: Padding::Zero,
        init: Init::He,
    };
    let mut params = Params::<f64>::new();
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let conv = Conv2::new(&mut params, "conv", config, &mut rng)
        .unwrap()
        .with_arithmetic(Arithmetic::Single);
    let x = test_array::<f64>(&[3, 3, 13, 11], 1);
    let run = |layer: &Conv2| {
        let tape = Tape::new();
        let p = params.bind(&tape);
        let xv = tape.var(x.clone());
        let y = layer.forward(&p, xv).unwrap();
        let loss = y.powi(2).unwrap().sum().unwrap();
        let grads = tape.backward(loss, &[xv]).unwrap();
        (y.to_array(), grads.get(xv).unwrap().clone())
    };
    let (y1, g1) = run(&conv);
    for threads in THREADS {
        let (y, g) = run(&conv.clone().with_threads(threads).unwrap());
        assert_eq!(bits(&y), bits(&y1), "{threads} threads");
        assert_eq!(bits(&g), bits(&g1), "{threads} threads");
    }
}

#[test]
fn zero_threads_is_an_error() {
    let x = test_array::<f64>(&[1, 2, 5, 5], 1);
    let w = test_array::<f64>(&[2, 2, 3, 3], 2);
    let b = test_array::<f64>(&[2], 3);
    let (xv, wv, bv) = (x.view(), w.view(), b.view());
    let err = conv_forward("conv", xv, wv, bv, Padding::Zero, Arithmetic::Native, 0);
    assert!(
        matches!(err, Err(TapeError::InvalidArgument { .. })),
        "{err:?}"
    );

    let tape = Tape::<f64>::new();
    let op = ConvOp {
        name: "conv".into(),
        padding: Padding::Zero,
        arithmetic: Arithmetic::Native,
        threads: 0,
    };
    let inputs = [tape.constant(x), tape.constant(w), tape.constant(b)];
    let err = tape.apply(op, &inputs);
    assert!(
        matches!(err, Err(TapeError::InvalidArgument { .. })),
        "{err:?}"
    );

    let config = ConvConfig {
        c_in: 2,
        c_out: 2,
        kernel: 3,
        padding: Padding::Zero,
        init: Init::He,
    };
    let mut params = Params::<f64>::new();
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let conv = Conv2::new(&mut params, "conv", config, &mut rng).unwrap();
    let err = conv.with_threads(0);
    assert!(matches!(err, Err(NnError::Config { .. })), "{err:?}");
}
