//! The published flow benchmarks the validation flows are judged against are
//! self-consistent: a typing error in a table would go unnoticed otherwise.
//! The tables are the constants of `diffphys::flow::validation` (Ghia, Ghia
//! and Shin 1982; Schäfer and Turek 1996), their one source.

use diffphys::flow::validation::{
    GhiaTable, Interval, DFG_2D1, DFG_2D2, DFG_CENTRE, DFG_HEIGHT, GHIA_1982, GHIA_X, GHIA_Y,
};

/// The indices on Ghia's 129-point grid of [`GHIA_Y`] (Table I) and
/// [`GHIA_X`] (Table II).
const GHIA_Y_POINTS: [u32; 17] = [
    1, 8, 9, 10, 14, 23, 37, 59, 65, 80, 95, 110, 123, 124, 125, 126, 129,
];
const GHIA_X_POINTS: [u32; 17] = [
    1, 9, 10, 11, 13, 21, 30, 31, 65, 104, 111, 117, 122, 123, 124, 125, 129,
];

/// (coordinate, value) of the smallest and the largest value.
fn extrema(coord: &[f64], values: &[f64]) -> ((f64, f64), (f64, f64)) {
    let mut lo = (coord[0], values[0]);
    let mut hi = lo;
    for (&c, &v) in coord.iter().zip(values) {
        if v < lo.1 {
            lo = (c, v);
        }
        if v > hi.1 {
            hi = (c, v);
        }
    }
    (lo, hi)
}

fn table(re: u32) -> &'static GhiaTable {
    GhiaTable::at(re).unwrap_or_else(|| panic!("Ghia's table at Re = {re}"))
}

#[test]
fn ghia_coordinates_are_points_of_the_129_grid() {
    for (name, points, coord) in [
        ("Table I, y", GHIA_Y_POINTS, GHIA_Y),
        ("Table II, x", GHIA_X_POINTS, GHIA_X),
    ] {
        for (p, c) in points.iter().zip(&coord) {
            let exact = (*p as f64 - 1.0) / 128.0;
            // Ghia prints four decimals, rounding half up (0.15625 -> 0.1563)
            assert!(
                (c - exact).abs() <= 0.5e-4 + 1e-12,
                "{name}: point {p} is {exact}, the table says {c}"
            );
        }
        assert!(coord.windows(2).all(|w| w[0] < w[1]), "{name}: ascending");
    }
    let res: Vec<u32> = GHIA_1982.iter().map(|t| t.re).collect();
    assert_eq!(res, [100, 400, 1000]);
}

#[test]
fn ghia_boundary_values_and_extrema_are_the_published_ones() {
    for t in &GHIA_1982 {
        let (re, u, v) = (t.re, &t.u, &t.v);
        // no slip at the bottom wall, the lid speed at the top
        assert_eq!((u[0], u[16]), (0.0, 1.0), "Re {re}: u at the walls");
        assert_eq!((v[0], v[16]), (0.0, 0.0), "Re {re}: v at the walls");
        // the primary vortex turns clockwise: u < 0 below the centre, v > 0 left of it
        assert!(u[1..8].iter().all(|&u| u < 0.0), "Re {re}: u < 0 low down");
        assert!(
            v[1..8].iter().all(|&v| v > 0.0),
            "Re {re}: v > 0 on the left"
        );
        assert!(
            v[9..16].iter().all(|&v| v < 0.0),
            "Re {re}: v < 0 on the right"
        );
        // u rises monotonically from its minimum to the lid
        let (lo, _) = extrema(&GHIA_Y, u);
        let from = GHIA_Y
            .iter()
            .position(|&c| c == lo.0)
            .expect("the minimum's y");
        assert!(
            u[from..].windows(2).all(|w| w[0] < w[1]),
            "Re {re}: u increases from its minimum to the lid"
        );
    }
    // The extrema the literature quotes from these tables.
    let cases = [
        (
            100,
            (0.4531, -0.21090),
            (0.8047, -0.24533),
            (0.2344, 0.17527),
        ),
        (
            400,
            (0.2813, -0.32726),
            (0.8594, -0.44993),
            (0.2266, 0.30203),
        ),
        (
            1000,
            (0.1719, -0.38289),
            (0.9063, -0.51550),
            (0.1563, 0.37095),
        ),
    ];
    for (re, u_min, v_min, v_max) in cases {
        let (lo, _) = extrema(&GHIA_Y, &table(re).u);
        assert_eq!(lo, u_min, "Re {re}: u_min (y, u)");
        let (lo, hi) = extrema(&GHIA_X, &table(re).v);
        assert_eq!(lo, v_min, "Re {re}: v_min (x, v)");
        assert_eq!(hi, v_max, "Re {re}: v_max (x, v)");
    }
    // u and v at the cavity's centre grow weaker as Re grows
    let centre_u: Vec<f64> = GHIA_1982.iter().map(|t| t.u[8]).collect();
    let centre_v: Vec<f64> = GHIA_1982.iter().map(|t| t.v[8]).collect();
    assert!(centre_u.windows(2).all(|w| w[0] < w[1]));
    assert!(centre_v.windows(2).all(|w| w[0] > w[1]));
}

#[test]
fn the_suspect_ghia_value_is_the_re_400_break_in_v() {
    // Table II, Re = 400: −0.23827 at x = 0.9063 between −0.44993 at 0.8594
    // and −0.22847 at 0.9453, kept as printed and flagged
    let flagged: Vec<(u32, usize)> = GHIA_1982
        .iter()
        .filter_map(|t| t.v_suspect.map(|k| (t.re, k)))
        .collect();
    assert_eq!(flagged, [(400, 11)]);
    assert_eq!((GHIA_X[11], table(400).v[11]), (0.9063, -0.23827));
}

#[test]
fn schaefer_turek_intervals_are_narrow_and_ordered() {
    let intervals: [(&str, Interval); 7] = [
        ("2D-1 cD", DFG_2D1.cd),
        ("2D-1 cL", DFG_2D1.cl),
        ("2D-1 dp", DFG_2D1.dp),
        ("2D-2 St", DFG_2D2.strouhal),
        ("2D-2 max cD", DFG_2D2.cd_max),
        ("2D-2 max cL", DFG_2D2.cl_max),
        ("2D-2 dp half a period on", DFG_2D2.dp_half_period),
    ];
    for (name, Interval { lo, hi }) in intervals {
        assert!(0.0 < lo && lo < hi, "{name}: {lo} < {hi}");
        assert!((hi - lo) / lo < 0.07, "{name}: a narrow interval");
    }
    // the cylinder is 0.005 below mid-height, which makes the lift non-zero
    assert!((DFG_HEIGHT / 2.0 - DFG_CENTRE[1] - 0.005).abs() < 1e-12);
}
