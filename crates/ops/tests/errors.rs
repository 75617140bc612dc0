//! The ops errors keep their kind through the tape.

use diffphys_ops::cg::CgError;
use diffphys_ops::OpsError;
use diffphys_tape::{ErrorKind, TapeError};

#[test]
fn errors_keep_their_kind_through_the_tape() {
    let cfl = OpsError::Cfl {
        op: "upwind_1d".into(),
        courant: 2.0,
        limit: 1.0,
    };
    assert_eq!(cfl.kind(), ErrorKind::Unstable);
    assert_eq!(TapeError::from(cfl).kind(), ErrorKind::Unstable);
    let nan = OpsError::NonFinite {
        op: "poisson".into(),
        what: "rhs".into(),
    };
    let wrapped: TapeError = nan.into();
    assert!(wrapped.is_non_finite());
    assert!(OpsError::Tape(wrapped).is_non_finite());
    let cg = CgError::InvalidArgument {
        message: "rtol".into(),
    };
    assert_eq!(TapeError::from(cg).kind(), ErrorKind::InvalidArgument);
}
