//! The reverse sweep is greedy: it visits only nodes between the requested
//! variables and the loss, asks an op only for the input gradients on such a path,
//! and sums the gradients of a value used more than once.

use std::cell::{Cell, RefCell};
use std::rc::Rc;

use diffphys_tape::{arr_dyn, ArrayD, ArrayViewD, BackwardArgs, Op, Result, Tape};

/// What a [`Probe`] op saw: how often its backward ran and the `needs_grad`
/// mask of each call.
#[derive(Clone, Default)]
struct Seen {
    backward_calls: Rc<Cell<usize>>,
    needs: Rc<RefCell<Vec<Vec<bool>>>>,
}

/// `y = Σₖ xₖ²` over any number of inputs of one shape; adjoint
/// `grad_xₖ = 2 xₖ grad_y`. Records every backward call in `seen`.
struct Probe {
    seen: Seen,
}

impl Op<f64> for Probe {
    fn name(&self) -> &str {
        "probe"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, f64>]) -> Result<Vec<ArrayD<f64>>> {
        let mut y = ArrayD::zeros(inputs[0].raw_dim());
        for x in inputs {
            y += &x.mapv(|v| v * v);
        }
        Ok(vec![y])
    }

    fn backward(&self, args: &BackwardArgs<'_, f64>) -> Result<Vec<Option<ArrayD<f64>>>> {
        let calls = &self.seen.backward_calls;
        calls.set(calls.get() + 1);
        self.seen.needs.borrow_mut().push(args.needs_grad.to_vec());
        let g = args.grad_out();
        Ok((0..args.inputs.len())
            .map(|k| args.needs(k).then(|| args.input(k).mapv(|x| 2.0 * x) * g))
            .collect())
    }
}

fn probe(seen: &Seen) -> Probe {
    Probe { seen: seen.clone() }
}

#[test]
fn a_branch_from_a_parameter_nobody_asks_about_is_never_swept() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0, 2.0]));
    let p = tape.var(arr_dyn(&[3.0, -1.0])); // a parameter, not requested
    let seen = Seen::default();
    let q = tape.apply(probe(&seen), &[p]).unwrap(); // q = p²
    let loss = x.mul(q).unwrap().sum().unwrap(); // Σ x p²
    assert_eq!(tape.stats().nodes, 3); // probe, mul, sum

    let grads = tape.backward(loss, &[x]).unwrap();
    assert_eq!(seen.backward_calls.get(), 0, "probe lies on no path from x");
    assert_eq!(grads.nodes_visited(), 2); // sum, mul
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[9.0, 1.0])); // ∂/∂x = p²
    assert!(grads.get(p).is_none(), "p was not requested");

    // Asked for p as well, the probe runs once and sees that p needs a gradient.
    let grads = tape.backward(loss, &[x, p]).unwrap();
    assert_eq!(seen.backward_calls.get(), 1);
    assert_eq!(grads.nodes_visited(), 3);
    assert_eq!(*seen.needs.borrow(), vec![vec![true]]);
    assert_eq!(grads.get(p).unwrap(), &arr_dyn(&[6.0, -4.0])); // ∂/∂p = 2 p x
}

#[test]
fn an_op_is_told_which_inputs_need_no_gradient() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0, 2.0]));
    let p = tape.var(arr_dyn(&[5.0, 5.0])); // on the graph, not requested
    let c = tape.constant(arr_dyn(&[7.0, 7.0]));
    let seen = Seen::default();
    let y = tape.apply(probe(&seen), &[x, p, c]).unwrap(); // x² + p² + c²
    let grads = y.sum().unwrap().backward(&[x]).unwrap();
    assert_eq!(seen.backward_calls.get(), 1);
    assert_eq!(*seen.needs.borrow(), vec![vec![true, false, false]]);
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[2.0, 4.0])); // ∂/∂x = 2x
}

#[test]
fn ops_on_constants_only_are_not_recorded_nor_swept() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0, 2.0]));
    let c = tape.constant(arr_dyn(&[3.0, 4.0]));
    let seen = Seen::default();
    let nodes_before = tape.stats().nodes;
    let c2 = tape.apply(probe(&seen), &[c]).unwrap(); // c², evaluated now
    assert_eq!(c2.to_array(), arr_dyn(&[9.0, 16.0]));
    assert_eq!(
        tape.stats().nodes,
        nodes_before,
        "no node for constants only"
    );
    assert!(!c2.requires_grad());

    let loss = x.mul(c2).unwrap().sum().unwrap();
    let grads = loss.backward(&[x]).unwrap();
    assert_eq!(seen.backward_calls.get(), 0);
    assert_eq!(grads.nodes_visited(), 2);
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[9.0, 16.0]));
}

#[test]
fn nodes_off_the_path_to_the_loss_are_not_visited() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[0.5, 1.5]));
    let seen = Seen::default();
    // Recorded, downstream of x, but the loss does not depend on them.
    let unused = tape.apply(probe(&seen), &[x]).unwrap();
    let _also_unused = unused.exp().unwrap().sum().unwrap();
    let loss = x.sin().unwrap().sum().unwrap();
    assert_eq!(tape.stats().nodes, 5);
    let grads = loss.backward(&[x]).unwrap();
    assert_eq!(grads.nodes_visited(), 2); // sum, sin
    assert_eq!(seen.backward_calls.get(), 0);
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[0.5, 1.5]).mapv(f64::cos));
}

#[test]
fn a_value_used_more_than_once_gets_the_summed_gradient() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[-1.0, 0.5, 3.0]));
    // d(x·x + x)/dx = 2x + 1
    let y = x.mul(x).unwrap().add(x).unwrap().sum().unwrap();
    let grads = y.backward(&[x]).unwrap();
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[-1.0, 2.0, 7.0]));

    // Through a plugin that takes x twice, and through concat and roll:
    // d Σ probe(x, x)/dx = 4x; d Σ concat(x, roll(x)) / dx = 2.
    let seen = Seen::default();
    let z = tape.apply(probe(&seen), &[x, x]).unwrap().sum().unwrap();
    let grads = z.backward(&[x]).unwrap();
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[-4.0, 2.0, 12.0]));
    assert_eq!(*seen.needs.borrow(), vec![vec![true, true]]);
    let c = diffphys_tape::Var::concat(&[x, x.roll(1, 0).unwrap()], 0).unwrap();
    let grads = c.sum().unwrap().backward(&[x]).unwrap();
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[2.0, 2.0, 2.0]));

    // Requesting the same variable twice gives it once, unchanged.
    let grads = y.backward(&[x, x]).unwrap();
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[-1.0, 2.0, 7.0]));
}

#[test]
fn backward_with_a_seed_gives_the_vector_jacobian_product() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0, 2.0, 3.0]));
    let y = x.mul(x).unwrap().add(x).unwrap(); // yᵢ = xᵢ² + xᵢ, a vector
    let seed = arr_dyn(&[1.0, -1.0, 0.5]);
    let grads = tape.backward_with_seed(y, seed, &[x]).unwrap();
    // (∂y/∂x)ᵀ s = (2x + 1) ⊙ s
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[3.0, -5.0, 3.5]));

    // The seed of a scalar loss is the scale of its gradient.
    let s = y.sum().unwrap();
    let scaled = tape
        .backward_with_seed(s, ArrayD::from_elem(ndarray::IxDyn(&[]), 2.0), &[x])
        .unwrap();
    assert_eq!(scaled.get(x).unwrap(), &arr_dyn(&[6.0, 10.0, 14.0]));
}

#[test]
fn an_intermediate_can_be_requested_alongside_a_leaf() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0, 2.0]));
    let h = x.exp().unwrap();
    let loss = h.mul(h).unwrap().sum().unwrap(); // Σ e^{2x}
    let grads = loss.backward(&[h, x]).unwrap();
    let e = arr_dyn(&[1.0, 2.0]).mapv(f64::exp);
    assert_eq!(grads.get(h).unwrap(), &e.mapv(|v| 2.0 * v)); // ∂/∂h = 2h
    let want = arr_dyn(&[1.0_f64, 2.0]).mapv(|v| 2.0 * (2.0 * v).exp()); // 2 e^{2x}
    for (g, w) in grads.get(x).unwrap().iter().zip(&want) {
        assert!((g - w).abs() <= 1e-14 * w);
    }
}
