//! SVG charts for the harness: line charts (optionally log-scaled), heat maps of
//! 2D fields, and quiver plots of 2D velocity fields.
//!
//! Everything is drawn with plotters' SVG backend into a string first and then
//! written to the file, so a write failure is a [`ReportError::Io`] naming the
//! path. Input that cannot be drawn (no series, no finite point, an empty field)
//! is a [`ReportError::Chart`], never a panic: plotters itself panics on empty or
//! NaN axis ranges, so every range is checked and padded before it reaches it.
//!
//! ```no_run
//! use diffphys_report::chart::{line_chart_svg, LineChart, Series};
//!
//! let series = [Series::new("naive f64", vec![(10.0, 1e-3), (100.0, 1e-9)])];
//! let chart = LineChart {
//!     title: "gradient error vs iterations",
//!     x_label: "CG iterations",
//!     y_label: "relative error",
//!     log_x: true,
//!     log_y: true,
//!     series: &series,
//! };
//! line_chart_svg(std::path::Path::new("out/error.svg"), &chart)?;
//! # Ok::<(), diffphys_report::ReportError>(())
//! ```

use std::path::Path;

use plotters::prelude::*;

use crate::format::format_value;
use crate::{ReportError, Result};

mod axes;
mod heatmap;
mod line;
mod panels;
mod quiver;

pub use heatmap::{
    heatmap_svg, heatmap_svg_string, heatmap_svg_string_with_axes, heatmap_svg_with_axes,
};
pub use line::{line_chart_svg, line_chart_svg_string};
pub use panels::{heatmap_panels_svg, heatmap_panels_svg_string, HeatmapPanels, Outline};
pub use quiver::{quiver_svg, quiver_svg_string};

/// One named curve of a [`LineChart`].
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// The legend entry.
    pub label: String,
    /// `(x, y)` points, drawn in the given order (sort by x for a curve). Points
    /// with a non-finite x are skipped; points with a finite x and a non-finite y
    /// are drawn as crosses on a separate "non-finite" row above the plot, so a
    /// failure shows where it happened. On a log axis a value `≤ 0` cannot be
    /// placed and is skipped.
    pub points: Vec<(f64, f64)>,
}

impl Series {
    /// A series from a label and its points.
    pub fn new(label: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            label: label.into(),
            points,
        }
    }

    /// The mean of several per-step curves (a rollout's error after each
    /// step, one curve per run): the point `(t + 1, mean_r runs[r][t])` for
    /// every step `t` that all runs reach. No runs, no points.
    ///
    /// ```
    /// use diffphys_report::chart::Series;
    /// let s = Series::mean_per_step("sol", &[vec![1.0, 2.0, 9.0], vec![3.0, 4.0]]);
    /// assert_eq!(s.points, vec![(1.0, 2.0), (2.0, 3.0)]);
    /// assert!(Series::mean_per_step("none", &[]).points.is_empty());
    /// ```
    pub fn mean_per_step(label: impl Into<String>, runs: &[Vec<f64>]) -> Self {
        let steps = runs.iter().map(Vec::len).min().unwrap_or(0);
        let n = runs.len() as f64;
        let points = (0..steps)
            .map(|t| ((t + 1) as f64, runs.iter().map(|v| v[t]).sum::<f64>() / n))
            .collect();
        Series::new(label, points)
    }
}

/// A line chart: one curve per [`Series`], a legend, and linear or log axes.
#[derive(Debug, Clone, Copy)]
pub struct LineChart<'a> {
    /// The caption.
    pub title: &'a str,
    /// The x-axis description.
    pub x_label: &'a str,
    /// The y-axis description.
    pub y_label: &'a str,
    /// Log-scale the x axis (base 10).
    pub log_x: bool,
    /// Log-scale the y axis (base 10).
    pub log_y: bool,
    /// The curves.
    pub series: &'a [Series],
}

const LINE_SIZE: (u32, u32) = (900, 560);

const HEATMAP_SIZE: (u32, u32) = (760, 640);

const COLORBAR_WIDTH: u32 = 120;

/// Heat maps average blocks of cells down to at most this many per axis, which
/// keeps a 1024² field to a few hundred kilobytes of SVG.
const HEATMAP_MAX_CELLS: usize = 128;

/// Quiver plots draw at most this many arrows per axis.
const QUIVER_MAX_ARROWS: usize = 32;

const FONT: &str = "sans-serif";

/// Ten distinguishable colours (the "tab10" palette).
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// The colour of series `i` in every line chart, so a method keeps its colour
/// across charts when callers keep the series order.
pub fn series_color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

fn chart_err(e: impl std::fmt::Display) -> ReportError {
    ReportError::Chart(e.to_string())
}

fn write_file(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|e| ReportError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::axes::{padded_range, AxisScale};
    use super::heatmap::{ColorScale, NON_FINITE_COLOR};
    use super::line::place;
    use super::*;

    #[test]
    fn diverging_scale_is_white_at_zero_and_symmetric() {
        let s = ColorScale::for_range(-2.0, 1.0);
        assert_eq!(s.color(0.0), RGBColor(247, 247, 247));
        assert_eq!(s.color(-2.0), RGBColor(33, 102, 172));
        assert_eq!(s.color(2.0), RGBColor(178, 24, 43));
        assert_eq!(s.color(f64::NAN), NON_FINITE_COLOR);
    }

    #[test]
    fn degenerate_ranges_are_padded() {
        assert_eq!(padded_range(0.0, 0.0, false), (-1.0, 1.0));
        assert_eq!(padded_range(-3.0, -3.0, true), (-3.5, -2.5));
        let (lo, hi) = padded_range(5.0, 5.0, false);
        assert!(lo < 5.0 && hi > 5.0);
    }

    #[test]
    fn gaps_split_runs_and_nan_goes_to_the_row() {
        let s = Series::new(
            "s",
            vec![(1.0, 1.0), (2.0, f64::NAN), (3.0, 2.0), (f64::NAN, 1.0)],
        );
        let p = place(&s, AxisScale { log: false }, AxisScale { log: false });
        assert_eq!(p.runs, vec![vec![(1.0, 1.0)], vec![(3.0, 2.0)]]);
        assert_eq!(p.non_finite_x, vec![2.0]);
    }
}
