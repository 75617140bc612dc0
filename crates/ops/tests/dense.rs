//! The dense operator of the CG tests: its spectrum, adjoint, diagonal and triplets.

use diffphys_ops::dense::DenseOperator;
use diffphys_ops::LinearOperator;
use diffphys_tape::{check_adjoint, test_array};
use ndarray::arr2;

#[test]
fn spectrum_is_as_asked_and_matrix_symmetric() {
    let lambdas = [1.0, 2.0, 5.0, 10.0, 100.0];
    let a = DenseOperator::<f64>::with_spectrum(&lambdas, 3);
    assert!(LinearOperator::<f64>::is_symmetric(&a));
    // trace = Σ λ = 118, ‖A‖_F² = Σ λ² = 10130 (orthogonal similarity).
    let m = a.matrix();
    let trace: f64 = m.diag().sum();
    let frob: f64 = m.iter().map(|v| v * v).sum();
    assert!((trace - 118.0).abs() < 1e-10, "{trace}");
    assert!((frob - 10130.0).abs() < 1e-8, "{frob}");
    // Not diagonal: the reflections mix the eigenvectors.
    assert!(m[[0, 1]].abs() > 1e-3);
}

#[test]
fn dense_operator_adjoint_diagonal_and_triplets() {
    let m = arr2(&[[1.0, 2.0, 0.0], [0.0, -1.0, 4.0]]);
    let a = DenseOperator::with_shapes(m, &[3], &[1, 2]).unwrap();
    assert!(!LinearOperator::<f64>::is_symmetric(&a));
    assert!(LinearOperator::<f64>::diagonal(&a).is_none());
    let x = test_array::<f64>(&[3], 1);
    let y = test_array::<f64>(&[1, 2], 2);
    let rep = check_adjoint(
        |x| a.apply(x).unwrap(),
        |y| a.apply_transpose(y).unwrap(),
        x.view(),
        y.view(),
    )
    .unwrap();
    assert!(rep.passes(1e-14), "{rep:?}");
    // zeros off the diagonal are dropped: (0,2) and (1,0)
    assert_eq!(LinearOperator::<f64>::triplets(&a).unwrap().len(), 4);
    assert!(DenseOperator::with_shapes(arr2(&[[1.0]]), &[2], &[1]).is_err());

    let sq = DenseOperator::new(arr2(&[[4.0, 1.0], [1.0, 3.0]]));
    let d = LinearOperator::<f64>::diagonal(&sq).unwrap();
    assert_eq!(d.as_slice().unwrap(), &[4.0, 3.0]);
}
