//! Charts are written as SVG text, and input that cannot be drawn is a typed error.

use diffphys_report::chart::{
    heatmap_svg, heatmap_svg_string, heatmap_svg_string_with_axes, line_chart_svg,
    line_chart_svg_string, quiver_svg, quiver_svg_string, LineChart, Series,
};
use diffphys_report::ReportError;
use ndarray::Array2;

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("diffphys-compare-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn chart<'a>(series: &'a [Series], log: bool) -> LineChart<'a> {
    LineChart {
        title: "error vs iterations",
        x_label: "iterations",
        y_label: "relative error",
        log_x: log,
        log_y: log,
        series,
    }
}

#[test]
fn line_chart_file_is_svg_with_every_label() {
    let dir = temp_dir("line");
    let path = dir.join("line.svg");
    let series = [
        Series::new(
            "naive f64",
            vec![(10.0, 1e-2), (100.0, 1e-7), (1000.0, 1e-12)],
        ),
        Series::new(
            "implicit f32",
            vec![(10.0, 3e-3), (100.0, f64::NAN), (1000.0, 2e-5)],
        ),
    ];
    line_chart_svg(&path, &chart(&series, true)).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("<svg"));
    assert!(text.trim_end().ends_with("</svg>"));
    assert!(text.contains("naive f64") && text.contains("implicit f32"));
    // The NaN point is drawn on the non-finite row, which is labelled.
    assert!(text.contains("non-finite"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn single_point_and_constant_series_are_drawn_not_rejected() {
    let series = [Series::new("one", vec![(3.0, 5.0)])];
    assert!(line_chart_svg_string(&chart(&series, false))
        .unwrap()
        .contains("<svg"));
    assert!(line_chart_svg_string(&chart(&series, true))
        .unwrap()
        .contains("<svg"));
    let flat = [Series::new("flat", vec![(1.0, 0.0), (2.0, 0.0)])];
    assert!(line_chart_svg_string(&chart(&flat, false))
        .unwrap()
        .contains("<svg"));
}

#[test]
fn only_non_finite_values_still_draw_the_failure_row() {
    let series = [Series::new(
        "all nan",
        vec![(1.0, f64::NAN), (2.0, f64::INFINITY)],
    )];
    let svg = line_chart_svg_string(&chart(&series, true)).unwrap();
    assert!(svg.contains("non-finite"));
}

#[test]
fn empty_or_unplaceable_line_charts_are_typed_errors() {
    let none: [Series; 0] = [];
    assert!(matches!(
        line_chart_svg_string(&chart(&none, false)),
        Err(ReportError::Chart(_))
    ));
    let empty = [Series::new("empty", vec![])];
    assert!(matches!(
        line_chart_svg_string(&chart(&empty, false)),
        Err(ReportError::Chart(_))
    ));
    let nan_x = [Series::new("nan x", vec![(f64::NAN, 1.0)])];
    assert!(matches!(
        line_chart_svg_string(&chart(&nan_x, false)),
        Err(ReportError::Chart(_))
    ));
    // Zero and negative x cannot sit on a log axis.
    let nonpositive = [Series::new("x ≤ 0", vec![(0.0, 1.0), (-1.0, 2.0)])];
    assert!(matches!(
        line_chart_svg_string(&chart(&nonpositive, true)),
        Err(ReportError::Chart(_))
    ));
    assert!(line_chart_svg_string(&chart(&nonpositive, false)).is_ok());
}

#[test]
fn unwritable_path_is_an_io_error() {
    let series = [Series::new("s", vec![(1.0, 1.0), (2.0, 3.0)])];
    let path = std::path::Path::new("/nonexistent-diffphys-dir/sub/chart.svg");
    let err = line_chart_svg(path, &chart(&series, false)).unwrap_err();
    assert!(matches!(err, ReportError::Io { .. }), "{err}");
}

#[test]
fn heatmap_of_signed_and_single_signed_fields() {
    let dir = temp_dir("heat");
    let signed = Array2::from_shape_fn((16, 8), |(i, j)| (i as f64 - 8.0) * (j as f64 + 1.0));
    heatmap_svg(&dir.join("signed.svg"), "signed", signed.view()).unwrap();
    let text = std::fs::read_to_string(dir.join("signed.svg")).unwrap();
    assert!(text.contains("<svg") && text.contains("min -64, max 56"));
    // Cells with i = 8 are exactly 0, white on the diverging scale.
    assert!(text.contains("#F7F7F7"), "diverging scale has white");

    let positive = Array2::from_shape_fn((300, 200), |(i, j)| (i + j) as f64);
    let svg = heatmap_svg_string("positive, block-averaged", positive.view()).unwrap();
    assert!(svg.contains("<svg") && svg.contains("max 498"));
    assert!(svg.contains("x (cell)") && svg.contains("y (cell)"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn heatmap_axes_can_be_named() {
    let field = Array2::from_shape_fn((33, 16), |(t, x)| (t * x) as f64);
    let svg =
        heatmap_svg_string_with_axes("u(t, x)", field.view(), ["time step", "x (cell)"]).unwrap();
    assert!(svg.contains("time step") && svg.contains("x (cell)"));
    assert!(
        !svg.contains("y (cell)"),
        "the default axis name is replaced"
    );
}

#[test]
fn heatmap_degenerate_fields() {
    let empty = Array2::<f64>::zeros((0, 4));
    assert!(matches!(
        heatmap_svg_string("empty", empty.view()),
        Err(ReportError::Chart(_))
    ));
    let constant = Array2::<f64>::zeros((4, 4));
    assert!(heatmap_svg_string("zeros", constant.view())
        .unwrap()
        .contains("<svg"));
    let mut holes = Array2::<f64>::ones((4, 4));
    holes[[1, 2]] = f64::NAN;
    let svg = heatmap_svg_string("holes", holes.view()).unwrap();
    assert!(svg.contains("1 non-finite"));
    let all_nan = Array2::<f64>::from_elem((3, 3), f64::NAN);
    assert!(heatmap_svg_string("nan", all_nan.view())
        .unwrap()
        .contains("no finite value"));
}

#[test]
fn quiver_draws_arrows_and_rejects_mismatched_shapes() {
    let dir = temp_dir("quiver");
    let n = 40;
    let c = n as f64 / 2.0;
    // A solid-body rotation u = −(y − c), v = x − c.
    let u = Array2::from_shape_fn((n, n), |(_, j)| -(j as f64 + 0.5 - c));
    let v = Array2::from_shape_fn((n, n), |(i, _)| i as f64 + 0.5 - c);
    quiver_svg(&dir.join("q.svg"), "rotation", u.view(), v.view()).unwrap();
    let text = std::fs::read_to_string(dir.join("q.svg")).unwrap();
    assert!(text.contains("<svg") && text.contains("<polyline"));
    let short = Array2::<f64>::zeros((n, n - 1));
    assert!(matches!(
        quiver_svg_string("bad", u.view(), short.view()),
        Err(ReportError::Chart(_))
    ));
    let zero = Array2::<f64>::zeros((5, 5));
    assert!(quiver_svg_string("still", zero.view(), zero.view())
        .unwrap()
        .contains("<svg"));
    std::fs::remove_dir_all(dir).unwrap();
}
