//! Every primitive op: forward values against hand-computed references, gradients
//! against central finite differences in f64, and a run in f32 compared with f64.

#[macro_use]
mod common;

use common::{away_from_zero, positive, tenths};
use diffphys_tape::{arr_dyn, test_array, ArrayD, IxDyn, Tape, Var};
use ndarray::{array, Array2};

fn d2(a: Array2<f64>) -> ArrayD<f64> {
    a.into_dyn()
}

/// A value and a gradient.
type Pair = (ArrayD<f64>, ArrayD<f64>);

/// Value of `f` at `x` on a fresh f64 tape, and the gradient of `sum(f(x))`.
fn eval1<F>(x: ArrayD<f64>, f: F) -> Pair
where
    F: for<'t> Fn(Var<'t, f64>) -> diffphys_tape::Result<Var<'t, f64>>,
{
    let tape = Tape::new();
    let v = tape.var(x);
    let y = f(v).unwrap();
    let grads = y.sum().unwrap().backward(&[v]).unwrap();
    (y.to_array(), grads.get(v).unwrap().clone())
}

/// Agreement to a few ulps: the tape and the reference evaluate the same formula.
#[track_caller]
fn assert_all_close(what: &str, actual: &ArrayD<f64>, expected: &ArrayD<f64>) {
    assert_eq!(actual.shape(), expected.shape(), "{what}");
    for (a, e) in actual.iter().zip(expected) {
        assert!(
            (a - e).abs() <= 1e-14 * e.abs().max(1.0),
            "{what}: {actual} != {expected}"
        );
    }
}

// ---------------------------------------------------------------- unary

#[test]
fn unary_values_and_derivatives_match_the_formulas() {
    let x = arr_dyn(&[-1.5, -0.5, 0.5, 2.0]);
    let each = |f: fn(f64) -> f64| x.mapv(f);
    let cases: Vec<(&str, Pair, ArrayD<f64>, ArrayD<f64>)> = vec![
        // (name, (value, d sum/dx) from the tape, expected value, expected derivative)
        (
            "neg",
            eval1(x.clone(), |v| v.neg()),
            each(|x| -x),
            each(|_| -1.0),
        ),
        (
            "add_scalar",
            eval1(x.clone(), |v| v.add_scalar(0.75)),
            each(|x| x + 0.75),
            each(|_| 1.0),
        ),
        (
            "mul_scalar",
            eval1(x.clone(), |v| v.mul_scalar(-2.5)),
            each(|x| -2.5 * x),
            each(|_| -2.5),
        ),
        // d x³/dx = 3x²
        (
            "powi 3",
            eval1(x.clone(), |v| v.powi(3)),
            each(|x| x * x * x),
            each(|x| 3.0 * x * x),
        ),
        // d x⁻²/dx = −2x⁻³
        (
            "powi -2",
            eval1(x.clone(), |v| v.powi(-2)),
            each(|x| 1.0 / (x * x)),
            each(|x| -2.0 / (x * x * x)),
        ),
        // d x⁰/dx = 0
        (
            "powi 0",
            eval1(x.clone(), |v| v.powi(0)),
            each(|_| 1.0),
            each(|_| 0.0),
        ),
        (
            "exp",
            eval1(x.clone(), |v| v.exp()),
            each(f64::exp),
            each(f64::exp),
        ),
        (
            "sin",
            eval1(x.clone(), |v| v.sin()),
            each(f64::sin),
            each(f64::cos),
        ),
        (
            "cos",
            eval1(x.clone(), |v| v.cos()),
            each(f64::cos),
            each(|x| -x.sin()),
        ),
        // d tanh/dx = 1 − tanh²
        (
            "tanh",
            eval1(x.clone(), |v| v.tanh()),
            each(f64::tanh),
            each(|x| 1.0 - x.tanh().powi(2)),
        ),
        // relu' = 1 where x > 0, else 0
        (
            "relu",
            eval1(x.clone(), |v| v.relu()),
            each(|x| x.max(0.0)),
            each(|x| if x > 0.0 { 1.0 } else { 0.0 }),
        ),
        // σ' = σ(1 − σ)
        (
            "sigmoid",
            eval1(x.clone(), |v| v.sigmoid()),
            each(|x| 1.0 / (1.0 + (-x).exp())),
            each(|x| {
                let s = 1.0 / (1.0 + (-x).exp());
                s * (1.0 - s)
            }),
        ),
        (
            "abs",
            eval1(x.clone(), |v| v.abs()),
            each(f64::abs),
            each(f64::signum),
        ),
    ];
    for (name, (value, grad), want_value, want_grad) in cases {
        assert_all_close(&format!("{name} value"), &value, &want_value);
        assert_all_close(&format!("{name} derivative"), &grad, &want_grad);
    }

    // ln and sqrt on positive inputs: d ln x/dx = 1/x, d √x/dx = 1/(2√x).
    let p = arr_dyn(&[0.25, 1.0, 4.0]);
    let (y, g) = eval1(p.clone(), |v| v.ln());
    assert_all_close("ln value", &y, &p.mapv(f64::ln));
    assert_all_close("ln derivative", &g, &arr_dyn(&[4.0, 1.0, 0.25]));
    let (y, g) = eval1(p, |v| v.sqrt());
    assert_all_close("sqrt value", &y, &arr_dyn(&[0.5, 1.0, 2.0]));
    assert_all_close("sqrt derivative", &g, &arr_dyn(&[1.0, 0.5, 0.25]));
}

#[test]
fn kinks_take_the_documented_subgradients() {
    let x = arr_dyn(&[0.0, 0.0]);
    let (_, g) = eval1(x.clone(), |v| v.relu());
    assert_eq!(g, arr_dyn(&[0.0, 0.0])); // relu'(0) := 0
    let (_, g) = eval1(x, |v| v.abs());
    assert_eq!(g, arr_dyn(&[0.0, 0.0])); // |·|'(0) := 0

    // Ties of minimum and maximum send the whole gradient to the first input.
    let tape = Tape::<f64>::new();
    let a = tape.var(arr_dyn(&[1.0, 2.0]));
    let b = tape.var(arr_dyn(&[1.0, 3.0]));
    for y in [a.minimum(b).unwrap(), a.maximum(b).unwrap()] {
        let grads = y.sum().unwrap().backward(&[a, b]).unwrap();
        assert_eq!(grads.get(a).unwrap()[[0]], 1.0);
        assert_eq!(grads.get(b).unwrap()[[0]], 0.0);
    }
}

#[test]
fn sigmoid_saturates_without_overflow() {
    let (y, g) = eval1(arr_dyn(&[-800.0, 800.0]), |v| v.sigmoid());
    assert_eq!(y, arr_dyn(&[0.0, 1.0]));
    assert_eq!(g, arr_dyn(&[0.0, 0.0])); // σ(1 − σ) → 0 at both ends
}

#[test]
fn unary_ops_pass_gradient_checks_and_run_in_f32() {
    let x = [away_from_zero(&[3, 4], 1)];
    let p = [positive(&[3, 4], 2)];
    check_op!("neg", &x, |_, v| v[0].neg());
    check_op!("add_scalar", &x, |_, v| v[0].add_scalar(0.75));
    check_op!("mul_scalar", &x, |_, v| v[0].mul_scalar(-2.5));
    check_op!("powi 3", &x, |_, v| v[0].powi(3));
    check_op!("powi -2", &x, |_, v| v[0].powi(-2));
    check_op!("powi 0", &x, |_, v| v[0].powi(0));
    check_op!("exp", &x, |_, v| v[0].exp());
    check_op!("ln", &p, |_, v| v[0].ln());
    check_op!("sqrt", &p, |_, v| v[0].sqrt());
    check_op!("sin", &x, |_, v| v[0].sin());
    check_op!("cos", &x, |_, v| v[0].cos());
    check_op!("tanh", &x, |_, v| v[0].tanh());
    check_op!("relu", &x, |_, v| v[0].relu());
    check_op!("sigmoid", &x, |_, v| v[0].mul_scalar(3.0)?.sigmoid());
    check_op!("abs", &x, |_, v| v[0].abs());
    // A scalar (0-d) loss through a chain of them.
    check_op!("chain", &p, |_, v| v[0]
        .sqrt()?
        .ln()?
        .tanh()?
        .powi(2)?
        .sum());
}

// ---------------------------------------------------------------- binary

/// Shape pairs: equal, a column against a row, a scalar against a matrix, a missing
/// leading axis, stretched axes on both sides.
const BROADCAST_PAIRS: [(&[usize], &[usize]); 5] = [
    (&[2, 3], &[2, 3]),
    (&[3, 1], &[4]),
    (&[], &[2, 2]),
    (&[2, 3, 4], &[3, 1]),
    (&[2, 1, 4], &[3, 1]),
];

#[test]
fn binary_values_broadcast_by_numpy_rules() {
    let tape = Tape::<f64>::new();
    let col = tape.var(d2(array![[1.0], [2.0], [3.0]])); // [3, 1]
    let row = tape.var(arr_dyn(&[10.0, 20.0])); // [2]
    let y = col.add(row).unwrap();
    assert_eq!(
        y.to_array(),
        d2(array![[11.0, 21.0], [12.0, 22.0], [13.0, 23.0]])
    );
    let y = col.div(row).unwrap();
    assert_eq!(y.to_array()[[2, 1]], 3.0 / 20.0);
    let y = col
        .sub(row)
        .unwrap()
        .maximum(col.mul(row).unwrap().neg().unwrap());
    assert_eq!(y.unwrap().to_array()[[0, 0]], -9.0); // max(1 − 10, −10)

    // d Σ(col + row)/d col = 2 per entry (each row entry meets it), d/d row = 3.
    let loss = col.add(row).unwrap().sum().unwrap();
    let grads = loss.backward(&[col, row]).unwrap();
    assert_eq!(
        grads.get(col).unwrap(),
        &ArrayD::from_elem(IxDyn(&[3, 1]), 2.0)
    );
    assert_eq!(
        grads.get(row).unwrap(),
        &ArrayD::from_elem(IxDyn(&[2]), 3.0)
    );
}

#[test]
fn binary_ops_pass_gradient_checks_with_broadcasting_and_run_in_f32() {
    for (k, (sa, sb)) in BROADCAST_PAIRS.iter().enumerate() {
        let seed = 10 * k as u64;
        let ab = [test_array::<f64>(sa, seed), test_array::<f64>(sb, seed + 1)];
        check_op!("add", &ab, |_, v| v[0].add(v[1]));
        check_op!("sub", &ab, |_, v| v[0].sub(v[1]));
        check_op!("mul", &ab, |_, v| v[0].mul(v[1]));
        let nonzero_b = [ab[0].clone(), away_from_zero(sb, seed + 2)];
        check_op!("div", &nonzero_b, |_, v| v[0].div(v[1]));
        // Never tied: odd tenths against even tenths.
        let untied = [tenths(sa, seed + 3, true), tenths(sb, seed + 4, false)];
        check_op!("minimum", &untied, |_, v| v[0].minimum(v[1]));
        check_op!("maximum", &untied, |_, v| v[0].maximum(v[1]));
        let untied_swapped = [untied[1].clone(), untied[0].clone()];
        check_op!("minimum swapped", &untied_swapped, |_, v| v[0]
            .minimum(v[1]));
    }
}

// ---------------------------------------------------------------- select

#[test]
fn select_routes_values_and_gradients_by_the_mask() {
    let tape = Tape::<f64>::new();
    let mask = array![[true], [false]].into_dyn(); // [2, 1]
    let a = tape.var(arr_dyn(&[1.0, 2.0, 3.0])); // [3]
    let b = tape.var(ArrayD::from_elem(IxDyn(&[2, 3]), -1.0));
    let y = Var::select(&mask, a, b).unwrap();
    assert_eq!(
        y.to_array(),
        d2(array![[1.0, 2.0, 3.0], [-1.0, -1.0, -1.0]])
    );
    let grads = y.sum().unwrap().backward(&[a, b]).unwrap();
    // a is taken in row 0 only: each entry once.
    assert_eq!(grads.get(a).unwrap(), &arr_dyn(&[1.0, 1.0, 1.0]));
    assert_eq!(
        grads.get(b).unwrap(),
        &d2(array![[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    );
}

#[test]
fn select_passes_gradient_checks_with_broadcasting_and_runs_in_f32() {
    let m = test_array::<f64>(&[3, 4], 5).mapv(|x| x > 0.0);
    let same = [test_array::<f64>(&[3, 4], 6), test_array::<f64>(&[3, 4], 7)];
    check_op!("select", &same, |_, v| Var::select(&m, v[0], v[1]));

    let col_mask = test_array::<f64>(&[3, 1], 8).mapv(|x| x > 0.0);
    let mixed = [test_array::<f64>(&[4], 9), test_array::<f64>(&[3, 4], 10)];
    check_op!("select broadcast", &mixed, |_, v| Var::select(
        &col_mask, v[0], v[1]
    ));
    let scalar_branch = [ArrayD::from_elem(IxDyn(&[]), 0.3), test_array(&[3, 4], 11)];
    check_op!("select scalar branch", &scalar_branch, |_, v| Var::select(
        &m, v[1], v[0]
    ));
}

// ---------------------------------------------------------------- reductions

#[test]
fn reduction_values_match_hand_sums() {
    let tape = Tape::<f64>::new();
    let x = tape.var(d2(array![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]));
    assert_eq!(x.sum().unwrap().item().unwrap(), 21.0);
    assert_eq!(x.sum_axis(0).unwrap().to_array(), arr_dyn(&[5.0, 7.0, 9.0]));
    assert_eq!(x.sum_axis(1).unwrap().to_array(), arr_dyn(&[6.0, 15.0]));
    assert_eq!(x.mean().unwrap().item().unwrap(), 3.5);
    let w = tape.var(d2(array![[1.0, 0.0, -1.0], [0.5, 0.0, 2.0]]));
    let d = x.dot(w).unwrap();
    assert_eq!(d.shape(), Vec::<usize>::new());
    assert_eq!(d.item().unwrap(), 1.0 - 3.0 + 2.0 + 12.0);
    // d(x·w)/dx = w, d(x·w)/dw = x
    let grads = d.backward(&[x, w]).unwrap();
    assert_eq!(grads.get(x).unwrap(), &w.to_array());
    assert_eq!(grads.get(w).unwrap(), &x.to_array());
    // d mean/dx = 1/n
    let grads = x.mean().unwrap().backward(&[x]).unwrap();
    assert_eq!(
        grads.get(x).unwrap(),
        &ArrayD::from_elem(IxDyn(&[2, 3]), 1.0 / 6.0)
    );
}

#[test]
fn reductions_pass_gradient_checks_and_run_in_f32() {
    let x = [test_array::<f64>(&[2, 3, 4], 20)];
    check_op!("sum", &x, |_, v| v[0].sum());
    check_op!("sum_axis 0", &x, |_, v| v[0].sum_axis(0));
    check_op!("sum_axis 1", &x, |_, v| v[0].sum_axis(1));
    check_op!("sum_axis 2", &x, |_, v| v[0].sum_axis(2));
    check_op!("mean", &x, |_, v| v[0].mean());
    let ab = [
        test_array::<f64>(&[3, 4], 21),
        test_array::<f64>(&[3, 4], 22),
    ];
    check_op!("dot", &ab, |_, v| v[0].dot(v[1]));
    check_op!("dot with itself", &ab[..1], |_, v| v[0].dot(v[0]));
}

// ---------------------------------------------------------------- linear algebra

#[test]
fn matmul_and_transpose_values() {
    let tape = Tape::<f64>::new();
    let a = tape.var(d2(array![[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]));
    let b = tape.var(d2(array![[1.0, 0.0, 2.0], [0.0, 1.0, -1.0]]));
    let c = a.matmul(b).unwrap();
    assert_eq!(
        c.to_array(),
        d2(array![[1.0, 2.0, 0.0], [3.0, 4.0, 2.0], [5.0, 6.0, 4.0]])
    );
    let at = a.transpose().unwrap();
    assert_eq!(at.to_array(), d2(array![[1.0, 3.0, 5.0], [2.0, 4.0, 6.0]]));
    assert!(at.value().is_standard_layout());
    // d Σ(A B)/dA = 1 Bᵀ: row sums of B in every row; d/dB = Aᵀ 1: column sums of A.
    let grads = c.sum().unwrap().backward(&[a, b]).unwrap();
    assert_eq!(
        grads.get(a).unwrap(),
        &d2(array![[3.0, 0.0], [3.0, 0.0], [3.0, 0.0]])
    );
    assert_eq!(
        grads.get(b).unwrap(),
        &d2(array![[9.0, 9.0, 9.0], [12.0, 12.0, 12.0]])
    );
}

#[test]
fn linear_algebra_passes_gradient_checks_and_runs_in_f32() {
    let ab = [
        test_array::<f64>(&[3, 4], 30),
        test_array::<f64>(&[4, 2], 31),
    ];
    check_op!("matmul", &ab, |_, v| v[0].matmul(v[1]));
    let sq = [test_array::<f64>(&[3, 3], 32)];
    check_op!("matmul square A A", &sq, |_, v| v[0].matmul(v[0]));
    check_op!("transpose", &ab[..1], |_, v| v[0].transpose());
    check_op!("A Aᵀ", &ab[..1], |_, v| v[0].matmul(v[0].transpose()?));
}

// ---------------------------------------------------------------- shape

#[test]
fn shape_op_values() {
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[0.0, 1.0, 2.0, 3.0, 4.0]));
    // NumPy: np.roll([0,1,2,3,4], 2) == [3,4,0,1,2]
    assert_eq!(
        x.roll(2, 0).unwrap().to_array(),
        arr_dyn(&[3.0, 4.0, 0.0, 1.0, 2.0])
    );
    assert_eq!(
        x.roll(-1, 0).unwrap().to_array(),
        arr_dyn(&[1.0, 2.0, 3.0, 4.0, 0.0])
    );
    assert_eq!(
        x.roll(7, 0).unwrap().to_array(),
        x.roll(2, 0).unwrap().to_array()
    );
    assert_eq!(x.roll(-10, 0).unwrap().to_array(), x.to_array());
    assert_eq!(x.slice(0, 1, 3).unwrap().to_array(), arr_dyn(&[1.0, 2.0]));
    assert_eq!(x.slice(0, 2, 2).unwrap().shape(), vec![0]);
    assert_eq!(
        x.pad(0, 2, 1).unwrap().to_array(),
        arr_dyn(&[0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 4.0, 0.0])
    );

    let m = tape.var(d2(array![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]));
    assert_eq!(
        m.roll(1, 1).unwrap().to_array(),
        d2(array![[3.0, 1.0, 2.0], [6.0, 4.0, 5.0]])
    );
    assert_eq!(
        m.reshape(&[3, 2]).unwrap().to_array(),
        d2(array![[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]) // row-major
    );
    assert_eq!(
        m.pad(1, 1, 0).unwrap().to_array(),
        d2(array![[0.0, 1.0, 2.0, 3.0], [0.0, 4.0, 5.0, 6.0]])
    );
    assert_eq!(
        m.slice(1, 2, 3).unwrap().to_array(),
        d2(array![[3.0], [6.0]])
    );
    let col = tape.var(d2(array![[7.0], [8.0]]));
    assert_eq!(
        Var::concat(&[m, col, m], 1).unwrap().to_array(),
        d2(array![
            [1.0, 2.0, 3.0, 7.0, 1.0, 2.0, 3.0],
            [4.0, 5.0, 6.0, 8.0, 4.0, 5.0, 6.0]
        ])
    );
    assert_eq!(
        Var::concat(&[m, m.mul_scalar(-1.0).unwrap()], 0)
            .unwrap()
            .shape(),
        vec![4, 3]
    );
    assert_eq!(
        col.broadcast_to(&[2, 2, 3]).unwrap().to_array(),
        ArrayD::from_shape_fn(IxDyn(&[2, 2, 3]), |i| 7.0 + i[1] as f64)
    );
    // Row-major in the logical order, whatever the memory order of the value.
    let column_major = tape.var(d2(array![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]].reversed_axes()));
    assert!(!column_major.value().is_standard_layout());
    assert_eq!(
        column_major.reshape(&[6]).unwrap().to_array(),
        arr_dyn(&[1.0, 4.0, 2.0, 5.0, 3.0, 6.0])
    );
    let one = tape.var(arr_dyn(&[5.0]));
    assert_eq!(one.reshape(&[]).unwrap().item().unwrap(), 5.0);
}

#[test]
fn shape_op_gradients_are_the_adjoint_placements() {
    // Σ over a roll counts every entry once; over a slice only the slice; over a
    // broadcast every entry as often as it was copied.
    let (_, g) = eval1(test_array(&[4, 3], 1), |v| v.roll(-5, 0));
    assert_eq!(g, ArrayD::from_elem(IxDyn(&[4, 3]), 1.0));
    let (_, g) = eval1(arr_dyn(&[1.0, 2.0, 3.0, 4.0]), |v| v.slice(0, 1, 3));
    assert_eq!(g, arr_dyn(&[0.0, 1.0, 1.0, 0.0]));
    let (_, g) = eval1(arr_dyn(&[1.0, 2.0]), |v| v.broadcast_to(&[3, 2]));
    assert_eq!(g, arr_dyn(&[3.0, 3.0]));
    // Weighted roll: the gradient of Σ wᵢ x[(i−1) mod n] w.r.t. x[j] is w[(j+1) mod n].
    let tape = Tape::<f64>::new();
    let x = tape.var(arr_dyn(&[1.0, 2.0, 3.0]));
    let w = tape.constant(arr_dyn(&[10.0, 20.0, 30.0]));
    let grads = x
        .roll(1, 0)
        .unwrap()
        .dot(w)
        .unwrap()
        .backward(&[x])
        .unwrap();
    assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[20.0, 30.0, 10.0]));
}

#[test]
fn shape_ops_pass_gradient_checks_and_run_in_f32() {
    let x = [test_array::<f64>(&[4, 5], 40)];
    check_op!("reshape", &x, |_, v| v[0].reshape(&[2, 10]));
    check_op!("reshape 3-D", &x, |_, v| v[0].reshape(&[5, 2, 2]));
    let col = [test_array::<f64>(&[3, 1], 41)];
    check_op!("broadcast_to", &col, |_, v| v[0].broadcast_to(&[2, 3, 4]));
    let scalar = [ArrayD::from_elem(IxDyn(&[]), 0.7)];
    check_op!("broadcast_to from 0-d", &scalar, |_, v| v[0]
        .broadcast_to(&[2, 2]));
    check_op!("slice axis 0", &x, |_, v| v[0].slice(0, 1, 3));
    check_op!("slice axis 1", &x, |_, v| v[0].slice(1, 0, 4));
    for shift in [-6, -1, 0, 1, 3, 12] {
        check_op!("roll axis 0", &x, |_, v| v[0].roll(shift, 0));
        check_op!("roll axis 1", &x, |_, v| v[0].roll(shift, 1));
    }
    check_op!("pad axis 0", &x, |_, v| v[0].pad(0, 2, 1));
    check_op!("pad axis 1", &x, |_, v| v[0].pad(1, 0, 3));
    let parts = [
        test_array::<f64>(&[2, 3], 42),
        test_array::<f64>(&[2, 1], 43),
        test_array::<f64>(&[2, 4], 44),
    ];
    check_op!("concat axis 1", &parts, |_, v| Var::concat(v, 1));
    check_op!("concat axis 0", &parts[..1], |_, v| Var::concat(
        &[v[0], v[0].transpose()?.reshape(&[2, 3])?],
        0
    ));
}

#[test]
fn a_stencil_of_primitives_passes_the_gradient_check() {
    // A periodic 1-D Laplacian with a nonlinear flux, the pattern the PDE code uses:
    // y = roll(x, 1) − 2x + roll(x, −1), loss = Σ tanh(y)·x² (scalar).
    let x = [test_array::<f64>(&[6, 3], 50)];
    check_op!("stencil", &x, |_, v| {
        let lap = v[0]
            .roll(1, 0)?
            .add(v[0].roll(-1, 0)?)?
            .sub(v[0].mul_scalar(2.0)?)?;
        lap.tanh()?.mul(v[0].powi(2)?)?.sum()
    });
}
