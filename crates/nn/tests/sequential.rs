//! The MLP and the sequential container against finite differences (f64), and
//! their configuration errors.

use diffphys_nn::{Activation, Bound, Dense, Init, Layer, Mlp, NnError, Params, Sequential};
use diffphys_tape::{check_gradient, test_array, GradCheckOptions, Tape};
use rand::SeedableRng;

fn rng(seed: u64) -> rand::rngs::StdRng {
    rand::rngs::StdRng::seed_from_u64(seed)
}

#[test]
fn mlp_gradients_match_finite_differences() {
    for activation in [Activation::Tanh, Activation::Identity] {
        let mut params = Params::<f64>::new();
        let mlp = Mlp::new(&mut params, "mlp", &[3, 5, 4, 2], activation, &mut rng(3)).unwrap();
        assert_eq!(mlp.depth(), 3);
        // Biases start at zero; give them values so their gradients are exercised
        // away from the initial point.
        let mut inputs = vec![test_array::<f64>(&[4, 3], 1)];
        inputs.extend(
            params
                .values()
                .iter()
                .enumerate()
                .map(|(k, v)| test_array::<f64>(v.shape(), 10 + k as u64)),
        );
        // L = Σ y², so every entry of every parameter and of x is checked.
        let report = check_gradient(
            |_, v| {
                let bound = Bound::from_vars(v[1..].to_vec());
                let y = mlp.forward(&bound, v[0])?;
                y.mul(y)?.sum()
            },
            &inputs,
            GradCheckOptions::for_type::<f64>(),
        )
        .unwrap();
        assert!(report.passed, "{activation:?}: {report:?}");
        assert_eq!(
            report.entries,
            4 * 3 + (3 * 5 + 5) + (5 * 4 + 4) + (4 * 2 + 2)
        );
    }
}

#[test]
fn sequential_gradients_match_finite_differences_and_equal_the_layers_in_turn() {
    let mut params = Params::<f64>::new();
    let mut r = rng(5);
    let d1 = Dense::new(&mut params, "d1", 3, 4, Init::Glorot, &mut r).unwrap();
    let d2 = Dense::new(&mut params, "d2", 4, 2, Init::Glorot, &mut r).unwrap();
    let net = Sequential::new()
        .with(d1.clone())
        .with(Activation::Tanh)
        .with(d2.clone());
    assert_eq!(net.len(), 3);
    let mut inputs = vec![test_array::<f64>(&[2, 3], 2)];
    inputs.extend(
        params
            .values()
            .iter()
            .enumerate()
            .map(|(k, v)| test_array::<f64>(v.shape(), 20 + k as u64)),
    );
    let report = check_gradient(
        |_, v| {
            let bound = Bound::from_vars(v[1..].to_vec());
            let y = net.forward(&bound, v[0])?;
            y.mul(y)?.sum()
        },
        &inputs,
        GradCheckOptions::for_type::<f64>(),
    )
    .unwrap();
    assert!(report.passed, "{report:?}");

    // The same as applying the layers by hand.
    let tape = Tape::<f64>::new();
    let p = params.bind(&tape);
    let x = tape.constant(inputs[0].clone());
    let by_hand = d2
        .forward(
            &p,
            Activation::Tanh.apply(d1.forward(&p, x).unwrap()).unwrap(),
        )
        .unwrap();
    assert_eq!(net.forward(&p, x).unwrap().to_array(), by_hand.to_array());
}

#[test]
fn mlp_is_seeded_counts_its_parameters_and_refuses_bad_sizes() {
    let (mut a, mut b) = (Params::<f64>::new(), Params::<f64>::new());
    Mlp::new(&mut a, "m", &[3, 8, 1], Activation::Relu, &mut rng(7)).unwrap();
    Mlp::new(&mut b, "m", &[3, 8, 1], Activation::Relu, &mut rng(7)).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.count(), 3 * 8 + 8 + 8 + 1);
    assert_eq!(a.names()[0], "m.0.weight");
    let mut p = Params::<f64>::new();
    assert!(matches!(
        Mlp::new(&mut p, "m", &[3], Activation::Relu, &mut rng(1)),
        Err(NnError::Config { .. })
    ));
    assert!(matches!(
        Mlp::new(&mut p, "z", &[3, 0, 1], Activation::Relu, &mut rng(1)),
        Err(NnError::Config { .. })
    ));
}

#[test]
fn frozen_parameters_get_no_gradient_and_record_no_node() {
    let mut params = Params::<f64>::new();
    let mlp = Mlp::new(&mut params, "m", &[2, 3, 1], Activation::Tanh, &mut rng(9)).unwrap();
    let tape = Tape::<f64>::new();
    let frozen = params.bind_frozen(&tape);
    let x = tape.var(test_array::<f64>(&[4, 2], 3));
    let y = mlp.forward(&frozen, x).unwrap().sum().unwrap();
    let grads = tape.backward(y, &[x]).unwrap();
    assert!(grads.get(x).is_some(), "the input still gets its gradient");
    assert!(frozen.vars().iter().all(|v| !v.requires_grad()));
    // Bound as constants, a network on a constant input records nothing.
    let before = tape.stats().nodes;
    mlp.forward(&frozen, tape.constant(test_array::<f64>(&[4, 2], 4)))
        .unwrap();
    assert_eq!(tape.stats().nodes, before);
}
