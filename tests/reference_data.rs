//! The published flow benchmarks shipped in data/ are self-consistent: a typing
//! error in a table the examples are judged against would go unnoticed otherwise.

use std::path::PathBuf;

use serde_json::Value;

fn load(name: &str) -> Value {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn numbers(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("an array")
        .iter()
        .map(|x| x.as_f64().expect("a number"))
        .collect()
}

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

#[test]
fn ghia_coordinates_are_points_of_the_129_grid() {
    let ghia = load("ghia1982_cavity.json");
    for (table, axis) in [
        ("u_along_vertical_centreline", "y"),
        ("v_along_horizontal_centreline", "x"),
    ] {
        let points = numbers(&ghia[table]["ghia_point"]);
        let coord = numbers(&ghia[table][axis]);
        assert_eq!(points.len(), 17, "{table}: 17 tabulated points");
        assert_eq!(coord.len(), 17, "{table}: 17 coordinates");
        for (p, c) in points.iter().zip(&coord) {
            let exact = (p - 1.0) / 128.0;
            // Ghia prints four decimals, rounding half up (0.15625 -> 0.1563)
            assert!(
                (c - exact).abs() <= 0.5e-4 + 1e-12,
                "{table}: point {p} is {exact}, the table says {axis} = {c}"
            );
        }
        assert!(coord.windows(2).all(|w| w[0] < w[1]), "{table}: ascending");
        for re in ["re100", "re400", "re1000"] {
            assert_eq!(numbers(&ghia[table][re]).len(), 17, "{table} {re}");
        }
    }
}

#[test]
fn ghia_boundary_values_and_extrema_are_the_published_ones() {
    let ghia = load("ghia1982_cavity.json");
    let u_table = &ghia["u_along_vertical_centreline"];
    let v_table = &ghia["v_along_horizontal_centreline"];
    let y = numbers(&u_table["y"]);
    let x = numbers(&v_table["x"]);
    for re in ["re100", "re400", "re1000"] {
        let u = numbers(&u_table[re]);
        let v = numbers(&v_table[re]);
        // no slip at the bottom wall, the lid speed at the top
        assert_eq!((u[0], u[16]), (0.0, 1.0), "{re}: u at the walls");
        assert_eq!((v[0], v[16]), (0.0, 0.0), "{re}: v at the walls");
        // the primary vortex turns clockwise: u < 0 below the centre, v > 0 left of it
        assert!(u[1..8].iter().all(|&u| u < 0.0), "{re}: u < 0 low down");
        assert!(v[1..8].iter().all(|&v| v > 0.0), "{re}: v > 0 on the left");
        assert!(
            v[9..16].iter().all(|&v| v < 0.0),
            "{re}: v < 0 on the right"
        );
        // u rises monotonically from its minimum to the lid
        let (lo, _) = extrema(&y, &u);
        let from = y.iter().position(|&c| c == lo.0).expect("the minimum's y");
        assert!(
            u[from..].windows(2).all(|w| w[0] < w[1]),
            "{re}: u increases from its minimum to the lid"
        );
    }
    // The extrema the literature quotes from these tables.
    let cases = [
        (
            "re100",
            (0.4531, -0.21090),
            (0.8047, -0.24533),
            (0.2344, 0.17527),
        ),
        (
            "re400",
            (0.2813, -0.32726),
            (0.8594, -0.44993),
            (0.2266, 0.30203),
        ),
        (
            "re1000",
            (0.1719, -0.38289),
            (0.9063, -0.51550),
            (0.1563, 0.37095),
        ),
    ];
    for (re, u_min, v_min, v_max) in cases {
        let (lo, _) = extrema(&y, &numbers(&u_table[re]));
        assert_eq!(lo, u_min, "{re}: u_min (y, u)");
        let (lo, hi) = extrema(&x, &numbers(&v_table[re]));
        assert_eq!(lo, v_min, "{re}: v_min (x, v)");
        assert_eq!(hi, v_max, "{re}: v_max (x, v)");
    }
    // u and v at the cavity's centre grow weaker as Re grows
    let centre = |table: &Value, re: &str| numbers(&table[re])[8];
    assert!(centre(u_table, "re100") < centre(u_table, "re400"));
    assert!(centre(u_table, "re400") < centre(u_table, "re1000"));
    assert!(centre(v_table, "re100") > centre(v_table, "re400"));
    assert!(centre(v_table, "re400") > centre(v_table, "re1000"));
}

#[test]
fn schaefer_turek_cases_are_consistent_with_their_definitions() {
    let st = load("schaefer_turek1996_cylinder.json");
    let nu = st["fluid"]["nu"].as_f64().unwrap();
    let d = st["geometry"]["cylinder_diameter"].as_f64().unwrap();
    for (case, re) in [("2D-1", 20.0), ("2D-2", 100.0)] {
        let c = &st["cases"][case];
        let um = c["um"].as_f64().unwrap();
        let ubar = c["ubar"].as_f64().unwrap();
        // Ubar = 2 Um / 3 (the mean of the parabola) and Re = Ubar D / nu
        assert!((ubar - 2.0 * um / 3.0).abs() < 1e-12, "{case}: Ubar");
        assert!((ubar * d / nu - re).abs() < 1e-9, "{case}: Re");
        assert_eq!(c["re"].as_f64().unwrap(), re, "{case}: Re as stated");
        for (name, interval) in c["intervals"].as_object().unwrap() {
            let [lo, hi] = numbers(interval)[..] else {
                panic!("{case} {name}: an interval is two numbers")
            };
            assert!(0.0 < lo && lo < hi, "{case} {name}: {lo} < {hi}");
            assert!((hi - lo) / lo < 0.07, "{case} {name}: a narrow interval");
        }
    }
    let centre = numbers(&st["geometry"]["cylinder_centre"]);
    let h = st["geometry"]["channel_height"].as_f64().unwrap();
    // the cylinder is 0.005 below mid-height, which makes the lift non-zero
    assert!((h / 2.0 - centre[1] - 0.005).abs() < 1e-12);
}
