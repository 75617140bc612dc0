//! Shared axes: linear or log scales, nice tick positions, padded ranges, and
//! the cell-index axes of heat maps and quiver plots.

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::Result;

use super::{chart_err, format_value, FONT};

/// A linear or base-10 log axis. Log axes are drawn as linear axes over `log10`
/// of the data, labelled with the original values.
#[derive(Debug, Clone, Copy)]
pub(super) struct AxisScale {
    pub(super) log: bool,
}

impl AxisScale {
    /// The plotted coordinate of a data value, or `None` if it cannot be placed.
    pub(super) fn map(self, v: f64) -> Option<f64> {
        if !v.is_finite() {
            None
        } else if self.log {
            (v > 0.0).then(|| v.log10())
        } else {
            Some(v)
        }
    }

    /// The data value at plotted coordinate `t`.
    pub(super) fn unmap(self, t: f64) -> f64 {
        if self.log {
            10f64.powf(t)
        } else {
            t
        }
    }

    pub(super) fn label(self, t: f64) -> String {
        format_value(self.unmap(t))
    }

    /// Labelled (bold) and grid-only (light) tick positions over the plotted range
    /// `[lo, hi]`: multiples of 1, 2 or 5 × 10^k on a linear axis; whole decades on
    /// a log axis spanning at least one, else nice data values mapped to it.
    pub(super) fn ticks(self, lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
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
pub(super) struct TickedAxis {
    pub(super) lo: f64,
    pub(super) hi: f64,
    pub(super) bold: Vec<f64>,
    pub(super) light: Vec<f64>,
}

impl TickedAxis {
    pub(super) fn new(lo: f64, hi: f64, (bold, light): (Vec<f64>, Vec<f64>)) -> Self {
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
pub(super) fn padded_range(lo: f64, hi: f64, log: bool) -> (f64, f64) {
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

pub(super) fn min_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// The axes of a field drawn over its cells (heat maps, quiver plots): no mesh,
/// named axes, values as [`format_value`] prints them.
pub(super) fn draw_cell_axes(
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
