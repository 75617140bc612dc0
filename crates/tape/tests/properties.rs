//! Property tests over random shapes: broadcasting of the binary ops and the
//! reductions.

use diffphys_tape::primitives::broadcast::broadcast_shape;
use diffphys_tape::{test_array, ArrayD, IxDyn, Result, Tape, TapeError, Var};
use proptest::prelude::*;

/// Two shapes that broadcast together, and the shape they broadcast to, computed
/// from how they were made (not by the code under test): both are cut from one
/// full shape by dropping leading axes and setting some axes to 1; an output axis
/// keeps its full length unless neither input has it at that length.
fn broadcast_pair() -> impl Strategy<Value = (Vec<usize>, Vec<usize>, Vec<usize>)> {
    prop::collection::vec(1_usize..=4, 0..=4)
        .prop_flat_map(|full| {
            let n = full.len();
            (
                Just(full),
                0..=n,
                0..=n,
                prop::collection::vec(any::<bool>(), n),
                prop::collection::vec(any::<bool>(), n),
            )
        })
        .prop_map(|(full, drop_a, drop_b, ones_a, ones_b)| {
            let cut = |drop: usize, ones: &[bool]| -> Vec<usize> {
                (drop..full.len())
                    .map(|k| if ones[k] { 1 } else { full[k] })
                    .collect()
            };
            let has = |drop: usize, ones: &[bool], k: usize| k >= drop && !ones[k];
            let expected = (drop_a.min(drop_b)..full.len())
                .map(|k| {
                    if has(drop_a, &ones_a, k) || has(drop_b, &ones_b, k) {
                        full[k]
                    } else {
                        1
                    }
                })
                .collect();
            (cut(drop_a, &ones_a), cut(drop_b, &ones_b), expected)
        })
}

type BinaryFn = for<'t> fn(Var<'t, f64>, Var<'t, f64>) -> Result<Var<'t, f64>>;

const BINARY_OPS: [(&str, BinaryFn); 6] = [
    ("add", |a, b| a.add(b)),
    ("sub", |a, b| a.sub(b)),
    ("mul", |a, b| a.mul(b)),
    ("div", |a, b| a.div(b)),
    ("minimum", |a, b| a.minimum(b)),
    ("maximum", |a, b| a.maximum(b)),
];

fn len(shape: &[usize]) -> usize {
    shape.iter().product()
}

fn close(a: f64, b: f64, scale: f64) -> bool {
    (a - b).abs() <= 1e-12 * scale.max(1.0)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn binary_ops_broadcast_and_send_gradients_back_to_input_shapes(
        (sa, sb, expected) in broadcast_pair(),
        seed in 0_u64..1000,
    ) {
        prop_assert_eq!(broadcast_shape("p", &sa, &sb).unwrap(), expected.clone());
        prop_assert_eq!(broadcast_shape("p", &sb, &sa).unwrap(), expected.clone());
        let a0 = test_array::<f64>(&sa, seed);
        let b0 = test_array::<f64>(&sb, seed + 1).mapv(|v| v + 2.0); // in [1, 3): no 1/0
        for (name, op) in BINARY_OPS {
            let tape = Tape::new();
            let (a, b) = (tape.var(a0.clone()), tape.var(b0.clone()));
            let y = op(a, b).unwrap();
            prop_assert_eq!(y.shape(), expected.clone(), "{} output shape", name);
            let grads = y.sum().unwrap().backward(&[a, b]).unwrap();
            prop_assert_eq!(grads.get(a).unwrap().shape(), &sa[..], "{} grad a", name);
            prop_assert_eq!(grads.get(b).unwrap().shape(), &sb[..], "{} grad b", name);
        }
    }

    #[test]
    fn gradients_of_a_broadcast_sum_are_the_multiplicities(
        (sa, sb, expected) in broadcast_pair(),
        seed in 0_u64..1000,
    ) {
        let tape = Tape::<f64>::new();
        let a = tape.var(test_array(&sa, seed));
        let b = tape.var(test_array(&sb, seed + 1));
        // Every entry of a meets len(out)/len(a) entries of the output.
        let (mult_a, mult_b) = (len(&expected) / len(&sa), len(&expected) / len(&sb));
        let sum = a.add(b).unwrap().sum().unwrap();
        let want = mult_a as f64 * a.value().sum() + mult_b as f64 * b.value().sum();
        prop_assert!(close(sum.item().unwrap(), want, len(&expected) as f64));

        let grads = sum.backward(&[a, b]).unwrap();
        let ga = ArrayD::from_elem(IxDyn(&sa), mult_a as f64);
        let gb = ArrayD::from_elem(IxDyn(&sb), mult_b as f64);
        prop_assert_eq!(grads.get(a).unwrap(), &ga);
        prop_assert_eq!(grads.get(b).unwrap(), &gb);
        // Σ(a − b): the same multiplicities, b with a minus sign.
        let grads = a.sub(b).unwrap().sum().unwrap().backward(&[b]).unwrap();
        prop_assert_eq!(grads.get(b).unwrap(), &gb.mapv(|v| -v));
    }

    #[test]
    fn reductions_agree_with_each_other(
        shape in prop::collection::vec(0_usize..=4, 1..=4),
        seed in 0_u64..1000,
    ) {
        let x0 = test_array::<f64>(&shape, seed);
        let n = len(&shape);
        let tape = Tape::<f64>::new();
        let x = tape.var(x0.clone());
        let total = x.sum().unwrap();
        prop_assert_eq!(total.shape(), Vec::<usize>::new());
        let total = total.item().unwrap();
        let ones = ArrayD::from_elem(IxDyn(&shape), 1.0);

        for axis in 0..shape.len() {
            let partial = x.sum_axis(axis).unwrap();
            let mut removed = shape.clone();
            removed.remove(axis);
            prop_assert_eq!(partial.shape(), removed);
            let s = partial.sum().unwrap();
            prop_assert!(close(s.item().unwrap(), total, n as f64));
            // Every entry enters the sum once, along whichever axis.
            let grads = s.backward(&[x]).unwrap();
            prop_assert_eq!(grads.get(x).unwrap(), &ones);
        }

        // Summing out axis 0 until none is left is the full sum.
        let mut v = x;
        while !v.shape().is_empty() {
            v = v.sum_axis(0).unwrap();
        }
        prop_assert!(close(v.item().unwrap(), total, n as f64));

        let grads = x.sum().unwrap().backward(&[x]).unwrap();
        prop_assert_eq!(grads.get(x).unwrap(), &ones);

        if n == 0 {
            let refused = matches!(x.mean(), Err(TapeError::InvalidArgument { .. }));
            prop_assert!(refused, "mean of an empty value is an error");
        } else {
            let mean = x.mean().unwrap();
            prop_assert!(close(mean.item().unwrap() * n as f64, total, n as f64));
            let grads = mean.backward(&[x]).unwrap();
            let want = 1.0 / n as f64;
            prop_assert!(grads.get(x).unwrap().iter().all(|&g| g == want));
        }
    }
}
