//! SVG charts for the harness: line charts (optionally log-scaled), heat maps of
//! 2D fields, and quiver plots of 2D velocity fields.
//!
//! Everything is drawn with plotters' SVG backend into a string first and then
//! written to the file, so a write failure is a [`CompareError::Io`] naming the
//! path. Input that cannot be drawn (no series, no finite point, an empty field)
//! is a [`CompareError::Chart`], never a panic: plotters itself panics on empty or
//! NaN axis ranges, so every range is checked and padded before it reaches it.
//!
//! ```no_run
//! use diffphys_compare::chart::{line_chart_svg, LineChart, Series};
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
//! # Ok::<(), diffphys_compare::CompareError>(())
//! ```

use std::path::Path;

use ndarray::ArrayView2;
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::{CompareError, Result};

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

fn chart_err(e: impl std::fmt::Display) -> CompareError {
    CompareError::Chart(e.to_string())
}

fn write_file(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|e| CompareError::io(path, e))
}

/// Formats an axis value with about three significant digits: `0.25`, `1200`,
/// `1e-8`, `3.2e5`.
pub fn format_value(x: f64) -> String {
    if x == 0.0 {
        return "0".to_string();
    }
    if !x.is_finite() {
        return x.to_string();
    }
    let a = x.abs();
    if (1e-3..1e5).contains(&a) {
        let s = format!("{x:.3}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        return s.to_string();
    }
    let s = format!("{x:.2e}");
    let (mantissa, exponent) = s.split_once('e').expect("{:e} formatting has an exponent");
    let mantissa = mantissa.trim_end_matches('0').trim_end_matches('.');
    format!("{mantissa}e{exponent}")
}

/// A linear or base-10 log axis. Log axes are drawn as linear axes over `log10`
/// of the data, labelled with the original values.
#[derive(Debug, Clone, Copy)]
struct AxisScale {
    log: bool,
}

impl AxisScale {
    /// The plotted coordinate of a data value, or `None` if it cannot be placed.
    fn map(self, v: f64) -> Option<f64> {
        if !v.is_finite() {
            None
        } else if self.log {
            (v > 0.0).then(|| v.log10())
        } else {
            Some(v)
        }
    }

    /// The data value at plotted coordinate `t`.
    fn unmap(self, t: f64) -> f64 {
        if self.log {
            10f64.powf(t)
        } else {
            t
        }
    }

    fn label(self, t: f64) -> String {
        format_value(self.unmap(t))
    }

    /// Labelled (bold) and grid-only (light) tick positions over the plotted range
    /// `[lo, hi]`: multiples of 1, 2 or 5 × 10^k on a linear axis; whole decades on
    /// a log axis spanning at least one, else nice data values mapped to it.
    fn ticks(self, lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
        if !self.log {
            return nice_ticks(lo, hi);
        }
        let span = hi - lo;
        if span < 1.0 {
            let (bold, light) = nice_ticks(10f64.powf(lo), 10f64.powf(hi));
            let to_log = |v: Vec<f64>| v.into_iter().filter(|&x| x > 0.0).map(f64::log10).collect();
            return (to_log(bold), to_log(light));
        }
        let every = (span / 8.0).ceil().max(1.0);
        let decades = (lo.ceil() as i64..=hi.floor() as i64).map(|k| k as f64);
        let in_decade = |multipliers: &'static [u8]| {
            (lo.floor() as i64..=hi.floor() as i64)
                .flat_map(move |k| {
                    multipliers
                        .iter()
                        .map(move |&m| k as f64 + f64::from(m).log10())
                })
                .filter(|&t| t >= lo && t <= hi)
        };
        // Under 2.5 decades, decades alone leave too few labels: add 2× and 5×.
        let bold: Vec<f64> = if span < 2.5 {
            in_decade(&[1, 2, 5]).collect()
        } else {
            decades
                .clone()
                .filter(|k| (k / every).fract() == 0.0)
                .collect()
        };
        let light: Vec<f64> = if every == 1.0 && span < 6.0 {
            in_decade(&[1, 2, 3, 4, 5, 6, 7, 8, 9]).collect()
        } else {
            decades.collect()
        };
        (bold, light)
    }
}

/// A linear plotters axis over `[lo, hi]` with ticks chosen here rather than by
/// plotters (which cannot place good ticks on our log10-transformed axes).
#[derive(Debug, Clone)]
struct TickedAxis {
    lo: f64,
    hi: f64,
    bold: Vec<f64>,
    light: Vec<f64>,
}

impl TickedAxis {
    fn new(lo: f64, hi: f64, (bold, light): (Vec<f64>, Vec<f64>)) -> Self {
        TickedAxis {
            lo,
            hi,
            bold,
            light,
        }
    }
}

impl Ranged for TickedAxis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        // `lo < hi` always: ranges are padded before an axis is built.
        let fraction = (value - self.lo) / (self.hi - self.lo);
        let pixels = f64::from(limit.1 - limit.0) * fraction;
        limit.0 + pixels.clamp(-1e6, 1e6).round() as i32
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            self.light.clone()
        } else {
            self.bold.clone()
        }
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.lo..self.hi
    }
}

/// Ticks at multiples of a step of 1, 2 or 5 × 10^k giving about eight labels over
/// `[lo, hi]`, and finer grid ticks between them.
fn nice_ticks(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    let raw = (hi - lo) / 8.0;
    if !(raw.is_finite() && raw > 0.0) {
        return (vec![lo], vec![]);
    }
    let magnitude = 10f64.powf(raw.log10().floor());
    let (mantissa, light_div) = [(1.0, 5.0), (2.0, 4.0), (5.0, 5.0), (10.0, 5.0)]
        .into_iter()
        .find(|&(m, _)| m * magnitude >= raw)
        .unwrap_or((10.0, 5.0));
    let step = mantissa * magnitude;
    let multiples = |step: f64| -> Vec<f64> {
        let first = (lo / step).ceil() as i64;
        let last = (hi / step).floor() as i64;
        (first..=last)
            .map(|k| k as f64 * step)
            .map(|t| if t.abs() < 1e-9 * step { 0.0 } else { t })
            .collect()
    };
    (multiples(step), multiples(step / light_div))
}

/// `[lo, hi]` widened so that plotters gets a non-empty range with a margin.
fn padded_range(lo: f64, hi: f64, log: bool) -> (f64, f64) {
    let span = hi - lo;
    if span <= 1e-12 * lo.abs().max(hi.abs()).max(1e-300) {
        let pad = if log {
            0.5
        } else if lo == 0.0 {
            1.0
        } else {
            0.1 * lo.abs()
        };
        (lo - pad, hi + pad)
    } else {
        (lo - 0.05 * span, hi + 0.05 * span)
    }
}

fn min_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// One series sorted into what can be drawn.
struct Placed {
    /// Contiguous runs of plottable points (a gap breaks the line).
    runs: Vec<Vec<(f64, f64)>>,
    /// Plotted x of points whose y is non-finite.
    non_finite_x: Vec<f64>,
}

fn place(series: &Series, sx: AxisScale, sy: AxisScale) -> Placed {
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
/// [`CompareError::Chart`] if there is no series or no point that can be placed
/// (finite, and positive on a log axis), [`CompareError::Io`] if the file cannot be
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
        return Err(CompareError::Chart(format!(
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
        return Err(CompareError::Chart(format!(
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

/// Piecewise-linear interpolation through evenly spaced colour anchors, `t ∈ [0, 1]`.
fn interpolate(anchors: &[(u8, u8, u8)], t: f64) -> RGBColor {
    let t = t.clamp(0.0, 1.0) * (anchors.len() - 1) as f64;
    let k = (t.floor() as usize).min(anchors.len() - 2);
    let f = t - k as f64;
    let mix = |a: u8, b: u8| (f64::from(a) + f * (f64::from(b) - f64::from(a))).round() as u8;
    let (a, b) = (anchors[k], anchors[k + 1]);
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Blue – white – red (ColorBrewer RdBu), for signed fields.
const DIVERGING: [(u8, u8, u8); 5] = [
    (33, 102, 172),
    (146, 197, 222),
    (247, 247, 247),
    (244, 165, 130),
    (178, 24, 43),
];
/// Dark purple to yellow (viridis), for single-signed fields.
const SEQUENTIAL: [(u8, u8, u8); 5] = [
    (68, 1, 84),
    (59, 82, 139),
    (33, 145, 140),
    (94, 201, 98),
    (253, 231, 37),
];
const NON_FINITE_COLOR: RGBColor = RGBColor(160, 160, 160);

/// How field values map to colours.
#[derive(Debug, Clone, Copy)]
enum ColorScale {
    /// Both signs: white at 0, symmetric limits `±vmax`.
    Diverging { vmax: f64 },
    /// One sign: `lo` to `hi` (equal for a constant field).
    Sequential { lo: f64, hi: f64 },
}

impl ColorScale {
    fn for_range(min: f64, max: f64) -> Self {
        if min < 0.0 && max > 0.0 {
            ColorScale::Diverging {
                vmax: max.max(-min),
            }
        } else {
            ColorScale::Sequential { lo: min, hi: max }
        }
    }

    fn color(self, v: f64) -> RGBColor {
        if !v.is_finite() {
            return NON_FINITE_COLOR;
        }
        match self {
            ColorScale::Diverging { vmax } => interpolate(&DIVERGING, 0.5 + 0.5 * v / vmax),
            ColorScale::Sequential { lo, hi } if hi > lo => {
                interpolate(&SEQUENTIAL, (v - lo) / (hi - lo))
            }
            ColorScale::Sequential { .. } => interpolate(&SEQUENTIAL, 0.5),
        }
    }

    /// The value range the colour bar shows.
    fn bar_range(self) -> (f64, f64) {
        match self {
            ColorScale::Diverging { vmax } => (-vmax, vmax),
            ColorScale::Sequential { lo, hi } if hi > lo => (lo, hi),
            ColorScale::Sequential { lo, hi } => padded_range(lo, hi, false),
        }
    }
}

/// The field averaged over blocks of `bx × by` cells (a block with a non-finite
/// cell is non-finite), with the block sizes.
fn block_average(
    field: ArrayView2<'_, f64>,
    max_cells: usize,
) -> (ndarray::Array2<f64>, usize, usize) {
    let (nx, ny) = field.dim();
    let (bx, by) = (nx.div_ceil(max_cells), ny.div_ceil(max_cells));
    if bx == 1 && by == 1 {
        return (field.to_owned(), 1, 1);
    }
    let out = ndarray::Array2::from_shape_fn((nx.div_ceil(bx), ny.div_ceil(by)), |(i, j)| {
        let block = field.slice(ndarray::s![
            i * bx..((i + 1) * bx).min(nx),
            j * by..((j + 1) * by).min(ny)
        ]);
        block.sum() / block.len() as f64
    });
    (out, bx, by)
}

/// Writes a heat map of a 2D cell-centred field at `path`. Axis 0 of `field` is
/// x (horizontal), axis 1 is y (vertical, upward), one square per cell (blocks of
/// cells averaged above 128 per axis). A field with both signs gets a diverging
/// blue–white–red scale centred on 0, a single-signed field a sequential one; a
/// colour bar shows the scale and the title gives the minimum and maximum.
/// Non-finite cells are grey and counted in the title.
///
/// # Errors
/// [`CompareError::Chart`] for an empty field, [`CompareError::Io`] if the file
/// cannot be written.
pub fn heatmap_svg(path: &Path, title: &str, field: ArrayView2<'_, f64>) -> Result<()> {
    heatmap_svg_with_axes(path, title, field, ["x (cell)", "y (cell)"])
}

/// [`heatmap_svg`] with named axes, `[first index, second index]`: for a
/// space-time field, say, `["time step", "x (cell)"]`.
///
/// # Errors
/// As [`heatmap_svg`].
pub fn heatmap_svg_with_axes(
    path: &Path,
    title: &str,
    field: ArrayView2<'_, f64>,
    axes: [&str; 2],
) -> Result<()> {
    let svg = heatmap_svg_string_with_axes(title, field, axes)?;
    write_file(path, &svg)
}

/// [`heatmap_svg`] into a string.
///
/// # Errors
/// As [`heatmap_svg`], without the I/O.
pub fn heatmap_svg_string(title: &str, field: ArrayView2<'_, f64>) -> Result<String> {
    heatmap_svg_string_with_axes(title, field, ["x (cell)", "y (cell)"])
}

/// [`heatmap_svg_with_axes`] into a string.
///
/// # Errors
/// As [`heatmap_svg`], without the I/O.
pub fn heatmap_svg_string_with_axes(
    title: &str,
    field: ArrayView2<'_, f64>,
    axes: [&str; 2],
) -> Result<String> {
    let (nx, ny) = field.dim();
    if nx == 0 || ny == 0 {
        return Err(CompareError::Chart(format!(
            "heat map '{title}' of an empty field (shape [{nx}, {ny}])"
        )));
    }
    let non_finite = field.iter().filter(|v| !v.is_finite()).count();
    let range = min_max(field.iter().copied().filter(|v| v.is_finite()));
    let scale = range.map(|(lo, hi)| ColorScale::for_range(lo, hi));
    let mut caption = match range {
        Some((lo, hi)) => format!(
            "{title}  [min {}, max {}]",
            format_value(lo),
            format_value(hi)
        ),
        None => format!("{title}  [no finite value]"),
    };
    if non_finite > 0 {
        caption.push_str(&format!("  ({non_finite} non-finite, grey)"));
    }
    let (blocks, bx, by) = block_average(field, HEATMAP_MAX_CELLS);

    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, HEATMAP_SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(chart_err)?;
        let root = root.titled(&caption, (FONT, 18)).map_err(chart_err)?;
        let (left, right) = root.split_horizontally(HEATMAP_SIZE.0 - COLORBAR_WIDTH);
        let mut ctx = ChartBuilder::on(&left)
            .margin(10)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..nx as f64, 0.0..ny as f64)
            .map_err(chart_err)?;
        draw_cell_axes(&mut ctx, axes)?;
        let (mx, my) = blocks.dim();
        let cells = (0..mx).flat_map(|i| (0..my).map(move |j| (i, j)));
        ctx.draw_series(cells.map(|(i, j)| {
            let x0 = (i * bx) as f64;
            let y0 = (j * by) as f64;
            let x1 = ((i + 1) * bx).min(nx) as f64;
            let y1 = ((j + 1) * by).min(ny) as f64;
            let color = scale.map_or(NON_FINITE_COLOR, |s| s.color(blocks[[i, j]]));
            Rectangle::new([(x0, y0), (x1, y1)], color.filled())
        }))
        .map_err(chart_err)?;
        if let Some(scale) = scale {
            draw_color_bar(&right, scale)?;
        }
        root.present().map_err(chart_err)?;
    }
    Ok(buf)
}

/// The axes of a field drawn over its cells (heat maps, quiver plots): no mesh,
/// named axes, values as [`format_value`] prints them.
fn draw_cell_axes(
    ctx: &mut ChartContext<'_, SVGBackend<'_>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    axes: [&str; 2],
) -> Result<()> {
    let fmt = |t: &f64| format_value(*t);
    ctx.configure_mesh()
        .disable_mesh()
        .x_desc(axes[0])
        .y_desc(axes[1])
        .x_label_formatter(&fmt)
        .y_label_formatter(&fmt)
        .axis_desc_style((FONT, 15))
        .label_style((FONT, 12))
        .draw()
        .map_err(chart_err)
}

fn draw_color_bar(area: &DrawingArea<SVGBackend<'_>, Shift>, scale: ColorScale) -> Result<()> {
    let (lo, hi) = scale.bar_range();
    let mut ctx = ChartBuilder::on(area)
        .margin_top(10)
        .margin_bottom(55)
        .margin_right(10)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(chart_err)?;
    // Snap rounding noise at the centre of a diverging scale to a plain 0.
    let fmt = |t: &f64| format_value(if t.abs() < 1e-9 * (hi - lo) { 0.0 } else { *t });
    ctx.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_label_formatter(&fmt)
        .label_style((FONT, 12))
        .draw()
        .map_err(chart_err)?;
    const STEPS: usize = 96;
    let step = (hi - lo) / STEPS as f64;
    ctx.draw_series((0..STEPS).map(|k| {
        let v0 = lo + k as f64 * step;
        let color = scale.color(v0 + 0.5 * step);
        Rectangle::new([(0.0, v0), (1.0, v0 + step)], color.filled())
    }))
    .map_err(chart_err)?;
    Ok(())
}

/// Writes a quiver plot of a 2D velocity field at `path`: arrows at cell centres
/// on a subsampled grid (at most 32 per axis), `u` the x component and `v` the y
/// component, both cell-centred of shape `[nx, ny]` (average staggered faces to
/// centres first). Arrow length is proportional to speed, the longest spanning
/// 90% of the sample spacing; the title gives the largest speed. Non-finite
/// vectors are red crosses.
///
/// # Errors
/// [`CompareError::Chart`] if `u` and `v` differ in shape or are empty,
/// [`CompareError::Io`] if the file cannot be written.
pub fn quiver_svg(
    path: &Path,
    title: &str,
    u: ArrayView2<'_, f64>,
    v: ArrayView2<'_, f64>,
) -> Result<()> {
    let svg = quiver_svg_string(title, u, v)?;
    write_file(path, &svg)
}

/// [`quiver_svg`] into a string.
///
/// # Errors
/// As [`quiver_svg`], without the I/O.
pub fn quiver_svg_string(
    title: &str,
    u: ArrayView2<'_, f64>,
    v: ArrayView2<'_, f64>,
) -> Result<String> {
    if u.dim() != v.dim() {
        return Err(CompareError::Chart(format!(
            "quiver '{title}': u has shape {:?}, v has shape {:?}",
            u.shape(),
            v.shape()
        )));
    }
    let (nx, ny) = u.dim();
    if nx == 0 || ny == 0 {
        return Err(CompareError::Chart(format!(
            "quiver '{title}' of an empty field (shape [{nx}, {ny}])"
        )));
    }
    let stride = nx.max(ny).div_ceil(QUIVER_MAX_ARROWS);
    let samples: Vec<(f64, f64, f64, f64)> = (stride / 2..nx)
        .step_by(stride)
        .flat_map(|i| (stride / 2..ny).step_by(stride).map(move |j| (i, j)))
        .map(|(i, j)| (i as f64 + 0.5, j as f64 + 0.5, u[[i, j]], v[[i, j]]))
        .collect();
    let max_speed = samples
        .iter()
        .filter(|s| s.2.is_finite() && s.3.is_finite())
        .map(|s| s.2.hypot(s.3))
        .fold(0.0, f64::max);
    let caption = format!("{title}  [max speed {}]", format_value(max_speed));
    let scale = if max_speed > 0.0 {
        0.9 * stride as f64 / max_speed
    } else {
        0.0
    };

    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, HEATMAP_SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(chart_err)?;
        let mut ctx = ChartBuilder::on(&root)
            .caption(&caption, (FONT, 18))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..nx as f64, 0.0..ny as f64)
            .map_err(chart_err)?;
        draw_cell_axes(&mut ctx, ["x (cell)", "y (cell)"])?;
        let arrow_color = RGBColor(30, 30, 30);
        for &(x, y, a, b) in &samples {
            if !(a.is_finite() && b.is_finite()) {
                ctx.draw_series(std::iter::once(Cross::new(
                    (x, y),
                    4,
                    RGBColor(214, 39, 40).stroke_width(2),
                )))
                .map_err(chart_err)?;
                continue;
            }
            let (dx, dy) = (a * scale, b * scale);
            let len = dx.hypot(dy);
            if len < 1e-3 * stride as f64 {
                ctx.draw_series(std::iter::once(Circle::new(
                    (x, y),
                    1,
                    arrow_color.filled(),
                )))
                .map_err(chart_err)?;
                continue;
            }
            // Centred on the cell; the head is two strokes at ±25° from the shaft.
            let tail = (x - 0.5 * dx, y - 0.5 * dy);
            let tip = (x + 0.5 * dx, y + 0.5 * dy);
            let head = 0.3 * len;
            let angle = dy.atan2(dx);
            let barb = |s: f64| {
                let t = angle + std::f64::consts::PI + s * 25f64.to_radians();
                (tip.0 + head * t.cos(), tip.1 + head * t.sin())
            };
            let style = arrow_color.stroke_width(1);
            ctx.draw_series([
                PathElement::new(vec![tail, tip], style),
                PathElement::new(vec![barb(1.0), tip, barb(-1.0)], style),
            ])
            .map_err(chart_err)?;
        }
        root.present().map_err(chart_err)?;
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_format_compactly() {
        assert_eq!(format_value(0.0), "0");
        assert_eq!(format_value(0.25), "0.25");
        assert_eq!(format_value(1200.0), "1200");
        assert_eq!(format_value(1e-8), "1e-8");
        assert_eq!(format_value(-3.25e5), "-3.25e5");
    }

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
