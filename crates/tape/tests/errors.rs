//! Every `TapeError` variant provoked, matched, and its message checked for the op
//! name and the shapes (or other context) it must carry.

use std::error::Error as _;

use diffphys_tape::{
    arr_dyn, ArrayD, ArrayViewD, BackwardArgs, IxDyn, Op, Pass, Result, Tape, TapeError, Var,
};
use ndarray::array;

/// What an op call returned.
type Outcome<'t> = Result<Var<'t, f64>>;

#[track_caller]
fn assert_mentions(err: &TapeError, words: &[&str]) {
    let message = err.to_string();
    for w in words {
        assert!(message.contains(w), "message {message:?} lacks {w:?}");
    }
}

// ---------------------------------------------------------------- ShapeMismatch

#[test]
fn shape_mismatches_name_the_op_and_both_shapes() {
    let tape = Tape::<f64>::new();
    let x3 = tape.var(arr_dyn(&[1.0, 2.0, 3.0]));
    let x4 = tape.var(arr_dyn(&[1.0, 2.0, 3.0, 4.0]));
    let m23 = tape.var(ArrayD::zeros(IxDyn(&[2, 3])));
    let m22 = tape.var(ArrayD::zeros(IxDyn(&[2, 2])));

    let cases: Vec<(&str, Outcome<'_>, Vec<usize>, Vec<usize>)> = vec![
        ("add", x3.add(x4), vec![3], vec![4]),
        ("sub", x4.sub(x3), vec![4], vec![3]),
        ("mul", m23.mul(x4), vec![2, 3], vec![4]),
        ("div", x3.div(m22), vec![3], vec![2, 2]),
        ("minimum", x3.minimum(x4), vec![3], vec![4]),
        ("maximum", x3.maximum(x4), vec![3], vec![4]),
        (
            "dot",
            x3.dot(m23.sum_axis(0).unwrap().pad(0, 0, 1).unwrap()),
            vec![3],
            vec![4],
        ),
        ("dot", m23.dot(x3), vec![2, 3], vec![3]), // dot does not broadcast
        ("matmul", m23.matmul(m22), vec![2, 3], vec![2, 2]),
        ("reshape", m23.reshape(&[4, 2]), vec![2, 3], vec![4, 2]),
        (
            "broadcast_to",
            x3.broadcast_to(&[3, 4]),
            vec![3],
            vec![3, 4],
        ),
        ("broadcast_to", m23.broadcast_to(&[3]), vec![2, 3], vec![3]),
        (
            "concat",
            Var::concat(&[m23, m22], 0),
            vec![2, 3],
            vec![2, 2],
        ),
        ("concat", Var::concat(&[m23, x3], 0), vec![2, 3], vec![3]),
        (
            "select",
            Var::select(&array![true, false].into_dyn(), x3, x3),
            vec![2],
            vec![3],
        ),
    ];
    for (op_name, result, want_lhs, want_rhs) in cases {
        let err = result.expect_err(op_name);
        assert!(
            matches!(&err, TapeError::ShapeMismatch { op, expected: lhs, found: rhs }
                if op == op_name && *lhs == want_lhs && *rhs == want_rhs),
            "{op_name}: {err:?}"
        );
        assert_mentions(
            &err,
            &[op_name, &format!("{want_lhs:?}"), &format!("{want_rhs:?}")],
        );
    }

    // A seed of the wrong shape for backward_with_seed.
    let err = tape
        .backward_with_seed(x3, ArrayD::zeros(IxDyn(&[4])), &[x3])
        .unwrap_err();
    assert!(matches!(err, TapeError::ShapeMismatch { .. }), "{err:?}");
    assert_mentions(&err, &["backward", "[4]", "[3]"]);
}

// ---------------------------------------------------------------- InvalidArgument

#[test]
fn invalid_arguments_name_the_op_and_what_was_wrong() {
    let tape = Tape::<f64>::new();
    let m = tape.var(ArrayD::zeros(IxDyn(&[2, 3])));
    let cube = tape.var(ArrayD::zeros(IxDyn(&[2, 2, 2])));
    let v = tape.var(arr_dyn(&[1.0, 2.0]));
    let empty = tape.var(ArrayD::zeros(IxDyn(&[0, 3])));

    let cases: Vec<(&str, Outcome<'_>, Vec<&str>)> = vec![
        ("sum_axis", m.sum_axis(2), vec!["axis 2", "[2, 3]"]),
        ("slice", m.slice(2, 0, 1), vec!["axis 2", "[2, 3]"]),
        (
            "slice",
            m.slice(1, 1, 4),
            vec!["1..4", "length 3", "[2, 3]"],
        ),
        ("slice", m.slice(0, 2, 1), vec!["2..1", "length 2"]),
        ("roll", m.roll(1, 5), vec!["axis 5", "[2, 3]"]),
        ("pad", m.pad(3, 1, 1), vec!["axis 3", "[2, 3]"]),
        ("concat", Var::concat(&[m, m], 2), vec!["axis 2", "[2, 3]"]),
        ("concat", Var::concat(&[], 0), vec!["at least one"]),
        ("transpose", cube.transpose(), vec!["2-D", "[2, 2, 2]"]),
        ("matmul", v.matmul(m), vec!["2-D", "[2]"]),
        ("matmul", m.matmul(cube), vec!["2-D", "[2, 2, 2]"]),
        ("mean", empty.mean(), vec!["empty", "[0, 3]"]),
    ];
    for (op_name, result, words) in cases {
        let err = result.expect_err(op_name);
        assert!(
            matches!(&err, TapeError::InvalidArgument { op, .. } if op == op_name),
            "{op_name}: {err:?}"
        );
        assert_mentions(&err, &words);
        assert_mentions(&err, &[op_name]);
    }

    let err = v.item().unwrap_err();
    assert!(matches!(&err, TapeError::InvalidArgument { op, .. } if op == "item"));
    assert_mentions(&err, &["item", "[2]"]);
}

// ---------------------------------------------------------------- Arity

/// A plugin that takes exactly two inputs and says so. No primitive can be
/// called with the wrong number of inputs (their methods fix it), and the `Op`
/// trait declares no arity for the tape to check, so an op checks its own.
struct NeedsTwo;

impl Op<f64> for NeedsTwo {
    fn name(&self) -> &str {
        "needs_two"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, f64>]) -> Result<Vec<ArrayD<f64>>> {
        if inputs.len() != 2 {
            return Err(TapeError::Arity {
                op: "needs_two".into(),
                expected: 2,
                found: inputs.len(),
            });
        }
        Ok(vec![&inputs[0] + &inputs[1]])
    }
}

#[test]
fn arity_errors_name_the_op_and_the_counts() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0]));
    assert!(tape.apply(NeedsTwo, &[x, x]).is_ok());
    let err = tape.apply(NeedsTwo, &[x]).unwrap_err();
    assert!(
        matches!(&err, TapeError::Arity { op, expected: 2, found: 1 } if op == "needs_two"),
        "{err:?}"
    );
    assert_mentions(&err, &["needs_two", "2 input", "got 1"]);
    let before = tape.stats().nodes;
    let err = tape.apply(NeedsTwo, &[x, x, x]).unwrap_err();
    assert!(matches!(err, TapeError::Arity { found: 3, .. }));
    assert_eq!(tape.stats().nodes, before, "a failed op records nothing");
}

// ---------------------------------------------------------------- NonScalarLoss

#[test]
fn backward_of_a_vector_without_a_seed_is_refused_with_its_shape() {
    let tape = Tape::<f64>::new();
    let x = tape.var(ArrayD::zeros(IxDyn(&[2, 3])));
    let y = x.exp().unwrap();
    let err = tape.backward(y, &[x]).unwrap_err();
    assert!(
        matches!(&err, TapeError::NonScalarLoss { shape } if *shape == vec![2, 3]),
        "{err:?}"
    );
    assert_mentions(&err, &["[2, 3]", "seed"]);
    // A one-element value of any rank is a scalar loss.
    let one = x.slice(0, 0, 1).unwrap().slice(1, 0, 1).unwrap();
    assert_eq!(one.shape(), vec![1, 1]);
    assert!(tape.backward(one, &[x]).is_ok());
}

// ---------------------------------------------------------------- ForeignVar

#[test]
fn variables_of_another_tape_are_refused_in_ops_and_in_backward() {
    let tape_a = Tape::<f64>::new();
    let tape_b = Tape::<f64>::new();
    let a = tape_a.var(arr_dyn(&[1.0, 2.0]));
    let b = tape_b.var(arr_dyn(&[3.0, 4.0]));
    let (ida, idb) = (tape_a.id(), tape_b.id());
    assert_ne!(ida, idb);

    let foreign = |err: TapeError, op_name: &str| {
        assert!(
            matches!(&err, TapeError::ForeignVar { op, expected, found }
                if op == op_name && *expected == ida && *found == idb),
            "{op_name}: {err:?}"
        );
        assert_mentions(&err, &[op_name, &ida.to_string(), &idb.to_string()]);
    };
    foreign(a.add(b).unwrap_err(), "add");
    foreign(a.dot(b).unwrap_err(), "dot");
    foreign(Var::concat(&[a, b], 0).unwrap_err(), "concat");
    foreign(
        Var::select(&array![true, false].into_dyn(), a, b).unwrap_err(),
        "select",
    );
    foreign(tape_a.apply(NeedsTwo, &[a, b]).unwrap_err(), "needs_two");

    // In backward: a requested variable of another tape, and a loss of another tape.
    let loss = a.sum().unwrap();
    foreign(tape_a.backward(loss, &[a, b]).unwrap_err(), "backward");
    let loss_b = b.sum().unwrap();
    foreign(tape_a.backward(loss_b, &[a]).unwrap_err(), "backward");
    // Gradients do not answer for a variable of another tape.
    let grads = loss.backward(&[a]).unwrap();
    assert!(grads.get(b).is_none());
}

// ---------------------------------------------------------------- NonFinite

#[test]
fn a_non_finite_forward_names_the_op_and_counts_the_entries() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0, -1.0, 2.0]));
    let err = x.ln().unwrap_err();
    assert!(
        matches!(&err, TapeError::NonFinite { op, pass: Pass::Forward, count: 1, len: 3 }
            if op == "ln"),
        "{err:?}"
    );
    assert_mentions(&err, &["ln", "forward", "1 of 3"]);

    let err = x.sqrt().unwrap_err();
    assert!(matches!(&err, TapeError::NonFinite { op, pass: Pass::Forward, .. } if op == "sqrt"));
    let zero = tape.var(arr_dyn(&[0.0, 1.0]));
    let err = x.slice(0, 0, 2).unwrap().div(zero).unwrap_err();
    assert!(matches!(&err, TapeError::NonFinite { op, .. } if op == "div"));
    let err = zero.powi(-1).unwrap_err();
    assert!(matches!(&err, TapeError::NonFinite { op, .. } if op == "powi"));

    // With the check off, the value is produced and the NaN is the caller's to see.
    tape.set_check_finite(false);
    let y = x.ln().unwrap();
    assert!(y.value()[[1]].is_nan());
    assert_eq!(y.value()[[0]], 0.0);
}

#[test]
fn a_non_finite_backward_names_the_op() {
    let tape = Tape::<f64>::new();
    // √0 = 0 is finite, but d√x/dx = 1/(2√x) is infinite at 0.
    let x = tape.var(arr_dyn(&[0.0, 4.0]));
    let y = x.sqrt().unwrap();
    assert_eq!(y.to_array(), arr_dyn(&[0.0, 2.0]));
    let err = y.sum().unwrap().backward(&[x]).unwrap_err();
    assert!(
        matches!(&err, TapeError::NonFinite { op, pass: Pass::Backward, count: 1, len: 2 }
            if op == "sqrt"),
        "{err:?}"
    );
    assert_mentions(&err, &["sqrt", "backward", "1 of 2"]);
}

// ---------------------------------------------------------------- BackwardNotSupported

/// A forward-only plugin: `y = 2x`, no backward.
struct ForwardOnly;

impl Op<f64> for ForwardOnly {
    fn name(&self) -> &str {
        "forward_only"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, f64>]) -> Result<Vec<ArrayD<f64>>> {
        Ok(vec![inputs[0].mapv(|x| 2.0 * x)])
    }
}

#[test]
fn a_forward_only_plugin_records_but_refuses_backward() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0, 2.0]));
    let y = tape.apply(ForwardOnly, &[x]).unwrap();
    assert_eq!(y.to_array(), arr_dyn(&[2.0, 4.0]));
    let err = y.sum().unwrap().backward(&[x]).unwrap_err();
    assert!(
        matches!(&err, TapeError::BackwardNotSupported { op } if op == "forward_only"),
        "{err:?}"
    );
    assert_mentions(&err, &["forward_only"]);

    // Not on the path from the requested variable: never asked, so no error.
    let w = tape.var(arr_dyn(&[1.0, 1.0]));
    let loss = y.mul(w).unwrap().sum().unwrap();
    let grads = loss.backward(&[w]).unwrap();
    assert_eq!(grads.get(w).unwrap(), &arr_dyn(&[2.0, 4.0]));
}

// ---------------------------------------------------------------- Op

#[derive(Debug)]
struct SolverDiverged {
    iterations: usize,
}

impl std::fmt::Display for SolverDiverged {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "diverged after {} iterations", self.iterations)
    }
}

impl std::error::Error for SolverDiverged {}

/// A plugin whose forward (or backward) fails with an error of its own.
struct FailingSolver {
    fail_forward: bool,
}

impl Op<f64> for FailingSolver {
    fn name(&self) -> &str {
        "solver"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, f64>]) -> Result<Vec<ArrayD<f64>>> {
        if self.fail_forward {
            return Err(TapeError::op("solver", SolverDiverged { iterations: 50 }));
        }
        Ok(vec![inputs[0].to_owned()])
    }

    fn backward(&self, _: &BackwardArgs<'_, f64>) -> Result<Vec<Option<ArrayD<f64>>>> {
        Err(TapeError::op("solver", SolverDiverged { iterations: 7 }))
    }
}

#[test]
fn a_plugin_error_keeps_its_source() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0]));
    let err = tape
        .apply(FailingSolver { fail_forward: true }, &[x])
        .unwrap_err();
    assert!(
        matches!(&err, TapeError::Op { op, .. } if op == "solver"),
        "{err:?}"
    );
    assert_mentions(&err, &["solver failed", "diverged after 50 iterations"]);
    // The message carries the cause once; the cause keeps its own type.
    assert!(
        err.source().is_none(),
        "the cause is in the message, not repeated"
    );
    let cause = err.op_cause().expect("the plugin's error is kept");
    let inner = cause
        .downcast_ref::<SolverDiverged>()
        .expect("its own type");
    assert_eq!(inner.iterations, 50);

    let y = tape
        .apply(
            FailingSolver {
                fail_forward: false,
            },
            &[x],
        )
        .unwrap();
    let err = y.sum().unwrap().backward(&[x]).unwrap_err();
    assert!(matches!(&err, TapeError::Op { op, .. } if op == "solver"));
    assert_mentions(&err, &["diverged after 7 iterations"]);
}

#[test]
fn holding_a_value_while_recording_is_not_a_panic() {
    let tape = Tape::<f64>::new();
    let x = tape.var(diffphys_tape::arr_dyn(&[1.0, 2.0]));
    let held = x.value();
    let y = x.mul(x).unwrap(); // used to panic: the value borrowed the tape
    let z = tape.var(held.mapv(|v| v + 1.0));
    assert_eq!(held[[1]], 2.0);
    assert_eq!(y.value()[[1]], 4.0);
    assert_eq!(z.value()[[0]], 2.0);
}

#[test]
fn a_missing_gradient_is_a_typed_error_and_errors_classify_themselves() {
    use diffphys_tape::ErrorKind;
    let tape = Tape::<f64>::new();
    let x = tape.var(diffphys_tape::arr_dyn(&[1.0, 2.0]));
    let w = tape.var(diffphys_tape::arr_dyn(&[3.0, 4.0]));
    let loss = x.mul(w).unwrap().sum().unwrap();
    let grads = tape.backward(loss, &[x]).unwrap();
    assert_eq!(grads.try_get(x).unwrap()[[0]], 3.0);
    let err = grads.try_get(w).unwrap_err();
    assert_eq!(err.kind(), ErrorKind::NoGradient);
    assert!(err.to_string().contains("not requested"), "{err}");

    let nan = tape
        .var(diffphys_tape::arr_dyn(&[-1.0]))
        .sqrt()
        .unwrap_err();
    assert_eq!(nan.kind(), ErrorKind::NonFinite);
    assert!(nan.is_non_finite());
    // A tape error wrapped by a plugin keeps its kind; another error is an Op.
    let wrapped = TapeError::op("solver", nan);
    assert_eq!(wrapped.kind(), ErrorKind::NonFinite);
    assert!(wrapped.is_non_finite());
    let io = TapeError::op("loader", std::io::Error::other("disk"));
    assert_eq!(io.kind(), ErrorKind::Op);
    assert!(!io.is_non_finite());
    let classified = TapeError::op_of_kind(
        "solver",
        std::io::Error::other("x"),
        ErrorKind::NotConverged,
    );
    assert_eq!(classified.kind(), ErrorKind::NotConverged);
    assert!(!TapeError::invalid("x", "y").is_non_finite());
    assert!(TapeError::check_arity("op", 2, 2).is_ok());
    assert_eq!(
        TapeError::check_arity("op", 2, 3).unwrap_err().kind(),
        ErrorKind::InvalidArgument
    );
}
