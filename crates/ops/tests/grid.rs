//! Grids and cell masks: cell centres, masks from centres, and bad grids refused.

use diffphys_ops::{Boundary, CellMask, Grid1, Grid2};

#[test]
fn grid_over_interval_has_right_centres() {
    let g = Grid1::over(-1.0, 1.0, 4, Boundary::Periodic).unwrap();
    assert_eq!(g.dx, 0.5);
    assert_eq!(g.centers(), vec![-0.75, -0.25, 0.25, 0.75]);
}

#[test]
fn masks_from_cell_centres() {
    let g = Grid2::new(4, 2, 0.5, 1.0, Boundary::Closed).unwrap();
    // centres x ∈ {0.25, 0.75, 1.25, 1.75}: an obstacle for x > 1
    let m = CellMask::from_fn2(&g, |c| c[0] < 1.0);
    assert_eq!(m.active_count(), 4);
    assert!(m.is_active(3) && !m.is_active(4));
    let mut f = ndarray::ArrayD::<f64>::ones(ndarray::IxDyn(&[4, 2]));
    m.zero_inactive(f.view_mut()).unwrap();
    assert_eq!(f.sum(), 4.0);
    assert!(m
        .zero_inactive(ndarray::ArrayD::<f64>::ones(ndarray::IxDyn(&[2, 4])).view_mut())
        .is_err());
    let m1 = CellMask::from_fn1(&Grid1::new(3, 1.0, 0.0, Boundary::Closed).unwrap(), |x| {
        x > 1.0
    });
    assert_eq!(m1.as_slice(), &[false, true, true]);
    assert_eq!(CellMask::all_active(&[2, 3]).active_count(), 6);
}

#[test]
fn bad_grids_are_errors() {
    assert!(Grid1::new(0, 1.0, 0.0, Boundary::Periodic).is_err());
    assert!(Grid1::new(3, f64::NAN, 0.0, Boundary::Periodic).is_err());
    assert!(Grid2::new(3, 3, 1.0, -1.0, Boundary::Closed).is_err());
    assert!(Grid1::over(1.0, 1.0, 3, Boundary::Closed).is_err());
}
