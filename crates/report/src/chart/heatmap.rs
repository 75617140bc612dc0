//! Heat maps of 2D fields with a colour bar (diverging about zero or
//! sequential).

use std::path::Path;

use ndarray::ArrayView2;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::{ReportError, Result};

use super::axes::{draw_cell_axes, min_max, padded_range};
use super::{
    chart_err, format_value, write_file, COLORBAR_WIDTH, FONT, HEATMAP_MAX_CELLS, HEATMAP_SIZE,
};

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

pub(super) const NON_FINITE_COLOR: RGBColor = RGBColor(160, 160, 160);

/// How field values map to colours.
#[derive(Debug, Clone, Copy)]
pub(super) enum ColorScale {
    /// Both signs: white at 0, symmetric limits `±vmax`.
    Diverging { vmax: f64 },
    /// One sign: `lo` to `hi` (equal for a constant field).
    Sequential { lo: f64, hi: f64 },
}

impl ColorScale {
    pub(super) fn for_range(min: f64, max: f64) -> Self {
        if min < 0.0 && max > 0.0 {
            ColorScale::Diverging {
                vmax: max.max(-min),
            }
        } else {
            ColorScale::Sequential { lo: min, hi: max }
        }
    }

    pub(super) fn color(self, v: f64) -> RGBColor {
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
    pub(super) fn bar_range(self) -> (f64, f64) {
        match self {
            ColorScale::Diverging { vmax } => (-vmax, vmax),
            ColorScale::Sequential { lo, hi } if hi > lo => (lo, hi),
            ColorScale::Sequential { lo, hi } => padded_range(lo, hi, false),
        }
    }
}

/// The field averaged over blocks of `bx × by` cells (a block with a non-finite
/// cell is non-finite), with the block sizes.
pub(super) fn block_average(
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
/// [`ReportError::Chart`] for an empty field, [`ReportError::Io`] if the file
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
        return Err(ReportError::Chart(format!(
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

pub(super) fn draw_color_bar(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    scale: ColorScale,
) -> Result<()> {
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
