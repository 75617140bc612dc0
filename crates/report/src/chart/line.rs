//! Line charts of series of points, optionally log-scaled, with a legend.

use std::path::Path;

use plotters::prelude::*;

use crate::{ReportError, Result};

use super::axes::{min_max, padded_range, AxisScale, TickedAxis};
use super::{chart_err, series_color, write_file, LineChart, Series, FONT, LINE_SIZE};

/// One series sorted into what can be drawn.
pub(super) struct Placed {
    /// Contiguous runs of plottable points (a gap breaks the line).
    pub(super) runs: Vec<Vec<(f64, f64)>>,
    /// Plotted x of points whose y is non-finite.
    pub(super) non_finite_x: Vec<f64>,
}

pub(super) fn place(series: &Series, sx: AxisScale, sy: AxisScale) -> Placed {
    let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut current = Vec::new();
    let mut non_finite_x = Vec::new();
    for &(x, y) in &series.points {
        match (sx.map(x), sy.map(y)) {
            (Some(px), Some(py)) => current.push((px, py)),
            (px, _) => {
                if let (Some(px), false) = (px, y.is_finite()) {
                    non_finite_x.push(px);
                }
                if !current.is_empty() {
                    runs.push(std::mem::take(&mut current));
                }
            }
        }
    }
    if !current.is_empty() {
        runs.push(current);
    }
    Placed { runs, non_finite_x }
}

/// The corner of the plot where the legend hides the fewest points.
fn legend_corner(
    placed: &[Placed],
    (x_lo, x_hi): (f64, f64),
    (y_lo, y_hi): (f64, f64),
    row_y: f64,
) -> SeriesLabelPosition {
    // Fractions of the plot each point sits at, 0 = left/bottom.
    let fractions = placed.iter().flat_map(|p| {
        p.runs
            .iter()
            .flatten()
            .copied()
            .chain(p.non_finite_x.iter().map(|&x| (x, row_y)))
            .map(|(x, y)| ((x - x_lo) / (x_hi - x_lo), (y - y_lo) / (y_hi - y_lo)))
    });
    let mut counts = [0usize; 4]; // upper right, upper left, lower right, lower left
    for (fx, fy) in fractions {
        let (right, left) = (fx > 0.6, fx < 0.4);
        let (upper, lower) = (fy > 0.65, fy < 0.35);
        counts[0] += usize::from(upper && right);
        counts[1] += usize::from(upper && left);
        counts[2] += usize::from(lower && right);
        counts[3] += usize::from(lower && left);
    }
    let best = (0..4).min_by_key(|&k| counts[k]).unwrap_or(0);
    [
        SeriesLabelPosition::UpperRight,
        SeriesLabelPosition::UpperLeft,
        SeriesLabelPosition::LowerRight,
        SeriesLabelPosition::LowerLeft,
    ][best]
        .clone()
}

/// Writes `chart` as an SVG file at `path`.
///
/// # Errors
/// [`ReportError::Chart`] if there is no series or no point that can be placed
/// (finite, and positive on a log axis), [`ReportError::Io`] if the file cannot be
/// written.
pub fn line_chart_svg(path: &Path, chart: &LineChart<'_>) -> Result<()> {
    let svg = line_chart_svg_string(chart)?;
    write_file(path, &svg)
}

/// [`line_chart_svg`] into a string.
///
/// # Errors
/// As [`line_chart_svg`], without the I/O.
pub fn line_chart_svg_string(chart: &LineChart<'_>) -> Result<String> {
    if chart.series.is_empty() {
        return Err(ReportError::Chart(format!(
            "line chart '{}' has no series",
            chart.title
        )));
    }
    let sx = AxisScale { log: chart.log_x };
    let sy = AxisScale { log: chart.log_y };
    let placed: Vec<Placed> = chart.series.iter().map(|s| place(s, sx, sy)).collect();

    let plotted = || placed.iter().flat_map(|p| p.runs.iter().flatten());
    let any_non_finite = placed.iter().any(|p| !p.non_finite_x.is_empty());
    let xs = plotted()
        .map(|p| p.0)
        .chain(placed.iter().flat_map(|p| p.non_finite_x.iter().copied()));
    let Some((x_lo, x_hi)) = min_max(xs) else {
        return Err(ReportError::Chart(format!(
            "line chart '{}' has no point that can be placed (all empty, non-finite{})",
            chart.title,
            if chart.log_x || chart.log_y {
                ", or ≤ 0 on a log axis"
            } else {
                ""
            }
        )));
    };
    let (x_lo, x_hi) = padded_range(x_lo, x_hi, chart.log_x);
    let (y_lo, y_hi) = match min_max(plotted().map(|p| p.1)) {
        Some((lo, hi)) => padded_range(lo, hi, chart.log_y),
        // Only non-finite points: an arbitrary band under the non-finite row.
        None => (0.0, 1.0),
    };
    let y_span = y_hi - y_lo;
    let (row_y, y_top) = if any_non_finite {
        (y_hi + 0.08 * y_span, y_hi + 0.14 * y_span)
    } else {
        (y_hi, y_hi)
    };

    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, LINE_SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(chart_err)?;
        let mut ctx = ChartBuilder::on(&root)
            .caption(chart.title, (FONT, 22))
            .margin(14)
            .x_label_area_size(48)
            .y_label_area_size(80)
            .build_cartesian_2d(
                TickedAxis::new(x_lo, x_hi, sx.ticks(x_lo, x_hi)),
                TickedAxis::new(y_lo, y_top, sy.ticks(y_lo, y_hi)),
            )
            .map_err(chart_err)?;
        let x_fmt = |t: &f64| sx.label(*t);
        let y_fmt = |t: &f64| sy.label(*t);
        ctx.configure_mesh()
            .x_desc(chart.x_label)
            .y_desc(chart.y_label)
            .x_label_formatter(&x_fmt)
            .y_label_formatter(&y_fmt)
            .axis_desc_style((FONT, 16))
            .label_style((FONT, 13))
            .light_line_style(RGBColor(235, 235, 235))
            .bold_line_style(RGBColor(210, 210, 210))
            .draw()
            .map_err(chart_err)?;

        if any_non_finite {
            ctx.draw_series(std::iter::once(PathElement::new(
                vec![(x_lo, row_y), (x_hi, row_y)],
                RGBColor(200, 200, 200).stroke_width(1),
            )))
            .map_err(chart_err)?;
            ctx.draw_series(std::iter::once(Text::new(
                "non-finite",
                (x_lo, row_y + 0.045 * y_span),
                (FONT, 13).into_font().color(&RGBColor(120, 120, 120)),
            )))
            .map_err(chart_err)?;
        }

        for (i, (series, p)) in chart.series.iter().zip(&placed).enumerate() {
            let color = series_color(i);
            for run in &p.runs {
                ctx.draw_series(LineSeries::new(run.iter().copied(), color.stroke_width(2)))
                    .map_err(chart_err)?;
            }
            // The markers carry the legend entry, so a series with no drawable
            // point still appears in it.
            let markers = p
                .runs
                .iter()
                .flatten()
                .map(move |&q| Circle::new(q, 3, color.filled()));
            let crosses = p
                .non_finite_x
                .iter()
                .map(move |&x| Cross::new((x, row_y), 5, color.stroke_width(2)));
            ctx.draw_series(crosses).map_err(chart_err)?;
            ctx.draw_series(markers)
                .map_err(chart_err)?
                .label(series.label.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 22, y)], color.stroke_width(2))
                });
        }
        ctx.configure_series_labels()
            .position(legend_corner(&placed, (x_lo, x_hi), (y_lo, y_top), row_y))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(160, 160, 160))
            .label_font((FONT, 13))
            .draw()
            .map_err(chart_err)?;
        root.present().map_err(chart_err)?;
    }
    Ok(buf)
}
