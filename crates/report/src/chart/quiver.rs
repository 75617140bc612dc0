//! Quiver plots of 2D velocity fields.

use std::path::Path;

use ndarray::ArrayView2;
use plotters::prelude::*;

use crate::{ReportError, Result};

use super::axes::draw_cell_axes;
use super::{chart_err, format_value, write_file, FONT, HEATMAP_SIZE, QUIVER_MAX_ARROWS};

/// Writes a quiver plot of a 2D velocity field at `path`: arrows at cell centres
/// on a subsampled grid (at most 32 per axis), `u` the x component and `v` the y
/// component, both cell-centred of shape `[nx, ny]` (average staggered faces to
/// centres first). Arrow length is proportional to speed, the longest spanning
/// 90% of the sample spacing; the title gives the largest speed. Non-finite
/// vectors are red crosses.
///
/// # Errors
/// [`ReportError::Chart`] if `u` and `v` differ in shape or are empty,
/// [`ReportError::Io`] if the file cannot be written.
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
        return Err(ReportError::Chart(format!(
            "quiver '{title}': u has shape {:?}, v has shape {:?}",
            u.shape(),
            v.shape()
        )));
    }
    let (nx, ny) = u.dim();
    if nx == 0 || ny == 0 {
        return Err(ReportError::Chart(format!(
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
