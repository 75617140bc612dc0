//! Several heat maps of fields of one shape in one figure, with one colour
//! scale, so that panels that are compared (a reference and the solvers set
//! against it) read on the same colours.

use std::path::Path;

use ndarray::ArrayView2;
use plotters::prelude::*;

use crate::{ReportError, Result};

use super::axes::{draw_cell_axes, min_max};
use super::heatmap::{block_average, draw_color_bar, ColorScale, NON_FINITE_COLOR};
use super::{chart_err, format_value, write_file, COLORBAR_WIDTH, FONT, HEATMAP_MAX_CELLS};

/// A circle drawn over every panel (a body's outline), in the fields' cell
/// units: `centre` as `(axis 0, axis 1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outline {
    /// The centre.
    pub centre: (f64, f64),
    /// The radius.
    pub radius: f64,
}

/// A figure of several fields of one shape on one colour scale.
#[derive(Debug, Clone)]
pub struct HeatmapPanels<'a> {
    /// The figure's title.
    pub title: &'a str,
    /// `(label, field)` per panel, in reading order (left to right, then
    /// down). Axis 0 of each field is drawn across, axis 1 upward.
    pub panels: &'a [(&'a str, ArrayView2<'a, f64>)],
    /// The axes' names, `[axis 0, axis 1]`.
    pub axes: [&'a str; 2],
    /// A body outlined on every panel.
    pub outline: Option<Outline>,
    /// Panels per row (at least 1).
    pub columns: usize,
}

/// Pixels per panel: wide enough for a 2:1 channel.
const PANEL_SIZE: (u32, u32) = (560, 330);

/// Writes [`heatmap_panels_svg_string`] at `path`.
///
/// # Errors
/// As [`heatmap_panels_svg_string`]; [`ReportError::Io`] if the file cannot
/// be written.
pub fn heatmap_panels_svg(path: &Path, figure: &HeatmapPanels<'_>) -> Result<()> {
    let svg = heatmap_panels_svg_string(figure)?;
    write_file(path, &svg)
}

/// The panels of `figure` as an SVG: one square per cell (blocks of cells
/// averaged above 128 per axis), one colour scale over every panel's finite
/// values (diverging about 0 when they take both signs) with its colour bar,
/// non-finite cells grey, and the outline drawn on each panel.
///
/// # Errors
/// [`ReportError::Chart`] without panels, for an empty field, for panels of
/// different shapes or for 0 columns.
pub fn heatmap_panels_svg_string(figure: &HeatmapPanels<'_>) -> Result<String> {
    let panels = figure.panels;
    let first = panels
        .first()
        .ok_or_else(|| ReportError::Chart(format!("panels '{}' without a field", figure.title)))?;
    let (nx, ny) = first.1.dim();
    if nx == 0 || ny == 0 {
        return Err(ReportError::Chart(format!(
            "panels '{}': an empty field (shape [{nx}, {ny}])",
            figure.title
        )));
    }
    if let Some((label, f)) = panels.iter().find(|p| p.1.dim() != (nx, ny)) {
        return Err(ReportError::Chart(format!(
            "panels '{}': '{label}' has shape {:?}, the first panel [{nx}, {ny}]",
            figure.title,
            f.dim()
        )));
    }
    if figure.columns == 0 {
        return Err(ReportError::Chart(format!(
            "panels '{}' in 0 columns",
            figure.title
        )));
    }
    let values = panels.iter().flat_map(|p| p.1.iter().copied());
    let range = min_max(values.filter(|v| v.is_finite()));
    let scale = range.map(|(lo, hi)| ColorScale::for_range(lo, hi));
    let caption = match range {
        Some((lo, hi)) => format!(
            "{}  [one scale: min {}, max {}]",
            figure.title,
            format_value(lo),
            format_value(hi)
        ),
        None => format!("{}  [no finite value]", figure.title),
    };
    let columns = figure.columns.min(panels.len());
    let rows = panels.len().div_ceil(columns);
    let size = (
        columns as u32 * PANEL_SIZE.0 + COLORBAR_WIDTH,
        rows as u32 * PANEL_SIZE.1 + 40,
    );
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(chart_err)?;
        let root = root.titled(&caption, (FONT, 18)).map_err(chart_err)?;
        let (left, right) = root.split_horizontally(size.0 - COLORBAR_WIDTH);
        for (area, (label, field)) in left.split_evenly((rows, columns)).iter().zip(panels) {
            let mut ctx = ChartBuilder::on(area)
                .caption(*label, (FONT, 15))
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(50)
                .build_cartesian_2d(0.0..nx as f64, 0.0..ny as f64)
                .map_err(chart_err)?;
            draw_cell_axes(&mut ctx, figure.axes)?;
            let (blocks, bx, by) = block_average(*field, HEATMAP_MAX_CELLS);
            let (mx, my) = blocks.dim();
            let cells = (0..mx).flat_map(|i| (0..my).map(move |j| (i, j)));
            ctx.draw_series(cells.map(|(i, j)| {
                let x = ((i * bx) as f64, ((i + 1) * bx).min(nx) as f64);
                let y = ((j * by) as f64, ((j + 1) * by).min(ny) as f64);
                let color = scale.map_or(NON_FINITE_COLOR, |s| s.color(blocks[[i, j]]));
                Rectangle::new([(x.0, y.0), (x.1, y.1)], color.filled())
            }))
            .map_err(chart_err)?;
            if let Some(o) = figure.outline {
                let circle: Vec<(f64, f64)> = (0..=96)
                    .map(|k| {
                        let a = std::f64::consts::TAU * k as f64 / 96.0;
                        (
                            o.centre.0 + o.radius * a.cos(),
                            o.centre.1 + o.radius * a.sin(),
                        )
                    })
                    .collect();
                ctx.draw_series(std::iter::once(PathElement::new(
                    circle,
                    BLACK.stroke_width(2),
                )))
                .map_err(chart_err)?;
            }
        }
        if let Some(scale) = scale {
            draw_color_bar(&right, scale)?;
        }
        root.present().map_err(chart_err)?;
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn panels_share_one_scale_and_refuse_mismatched_shapes() {
        let a = Array2::from_shape_fn((8, 4), |(i, j)| i as f64 - j as f64);
        let b = a.mapv(|v| 3.0 * v);
        let figure = HeatmapPanels {
            title: "two",
            panels: &[("reference", a.view()), ("tripled", b.view())],
            axes: ["x", "y"],
            outline: Some(Outline {
                centre: (2.0, 2.0),
                radius: 1.0,
            }),
            columns: 2,
        };
        let svg = heatmap_panels_svg_string(&figure).unwrap();
        assert!(svg.contains("reference") && svg.contains("tripled"));
        // One scale: the range of both panels together (b's extremes).
        assert!(
            svg.contains("min -9") && svg.contains("max 21"),
            "{svg:.400}"
        );
        let c = Array2::<f64>::zeros((4, 8));
        let bad = HeatmapPanels {
            panels: &[("a", a.view()), ("c", c.view())],
            ..figure.clone()
        };
        assert!(matches!(
            heatmap_panels_svg_string(&bad),
            Err(ReportError::Chart(m)) if m.contains("'c'")
        ));
        let none = HeatmapPanels {
            panels: &[],
            ..figure.clone()
        };
        assert!(heatmap_panels_svg_string(&none).is_err());
        let zero = HeatmapPanels {
            columns: 0,
            ..figure
        };
        assert!(heatmap_panels_svg_string(&zero).is_err());
    }
}
