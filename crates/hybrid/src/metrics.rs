//! Flow metrics of a learned rollout, as the learning library's
//! [`diffphys_learn::Metric`]s read them: one sample's fields (`u_x`, `u_y`,
//! any auxiliary after them) against the reference's.
//!
//! The relative L2 error of the whole state, `‖u − u_ref‖ / ‖u_ref‖`, has the
//! free stream in its denominator: in a wake most of `‖u_ref‖` is the uniform
//! inflow every solver gets right, so an error reads several times smaller
//! than the wake's error it is. [`deviation_error`] takes the free stream out
//! of the denominator; [`vorticity_error`] compares the rotation, which the
//! free stream does not carry at all.

use diffphys_flow::diagnostics::vorticity;
use diffphys_flow::{FlowState, Scene};
use diffphys_learn::relative_l2_fields;
use ndarray::{Array2, ArrayViewD, Axis};

/// One sample's fields, as a metric of a rollout reads them.
pub type Fields<'a, 'b> = &'a [ArrayViewD<'b, f64>];

/// The samples `p` and `r` as states of `scene`; `None` for other fields.
fn states(
    scene: &Scene,
    p: Fields<'_, '_>,
    r: Fields<'_, '_>,
) -> Option<(FlowState<f64>, FlowState<f64>)> {
    Some((scene.state_of(p).ok()?, scene.state_of(r).ok()?))
}

/// `sqrt(Σ a² / Σ b²)` over paired entries `(a, b)`.
fn ratio(pairs: impl Iterator<Item = (f64, f64)>) -> f64 {
    let (num, den) = pairs.fold((0.0, 0.0), |(n, d), (a, b)| (n + a * a, d + b * b));
    (num / den).sqrt()
}

/// The relative L2 error of the velocity's deviation from the free stream
/// `U = (U_x, U_y)`:
///
/// ```text
/// ‖u_p − u_r‖ / ‖u_r − U‖      over every face of both components
/// ```
///
/// A solver that misses the whole wake scores 1 however weak the wake is.
/// NaN for samples that are not states of `scene`.
pub fn deviation_error(
    scene: &Scene,
    free_stream: [f64; 2],
    p: Fields<'_, '_>,
    r: Fields<'_, '_>,
) -> f64 {
    let Some((p, r)) = states(scene, p, r) else {
        return f64::NAN;
    };
    velocity_deviation_error((&p.ux, &p.uy), &r, free_stream)
}

/// [`deviation_error`] of the velocity `(u_x, u_y)` against the state `r`'s:
/// `‖u − u_r‖ / ‖u_r − U‖` over every face of both components.
pub fn velocity_deviation_error(
    u: (&Array2<f64>, &Array2<f64>),
    r: &FlowState<f64>,
    free_stream: [f64; 2],
) -> f64 {
    let x = (u.0.iter())
        .zip(&r.ux)
        .map(|(a, b)| (a - b, b - free_stream[0]));
    let y = (u.1.iter())
        .zip(&r.uy)
        .map(|(a, b)| (a - b, b - free_stream[1]));
    ratio(x.chain(y))
}

/// The relative L2 error of the vorticity over the grid's inner nodes,
/// `‖ω_p − ω_r‖ / ‖ω_r‖` ([`diffphys_flow::diagnostics::vorticity`]). NaN
/// for samples that are not states of `scene`.
pub fn vorticity_error(scene: &Scene, p: Fields<'_, '_>, r: Fields<'_, '_>) -> f64 {
    let Some((p, r)) = states(scene, p, r) else {
        return f64::NAN;
    };
    let w = |s: &FlowState<f64>| vorticity(scene, s.ux.view(), s.uy.view()).ok();
    let (Some(wp), Some(wr)) = (w(&p), w(&r)) else {
        return f64::NAN;
    };
    ratio(wp.iter().zip(&wr).map(|(a, b)| (a - b, *b)))
}

/// The relative L2 error of the velocity `(u_x, u_y)` against the state
/// `r`'s, `‖u − u_r‖ / ‖u_r‖` over both components.
pub fn velocity_error(u: (&Array2<f64>, &Array2<f64>), r: &FlowState<f64>) -> f64 {
    let one = |a: &Array2<f64>| a.clone().insert_axis(Axis(0)).into_dyn();
    relative_l2_fields(&[one(u.0), one(u.1)], &[one(&r.ux), one(&r.uy)])
}

/// The vorticity of `states` (each a label and a state of `scene`) side by
/// side on one colour scale, streamwise to the right, two to a row, with a
/// circle of `(centre, radius)` outlined (the body), at `path`;
/// nothing is written without states.
///
/// # Errors
/// [`crate::HybridError::Flow`] for a state of another grid;
/// [`crate::HybridError::Learn`] (a report error) if the chart cannot be
/// written.
pub fn vorticity_chart(
    path: &std::path::Path,
    title: &str,
    states: &[(&str, &FlowState<f64>)],
    scene: &Scene,
    (centre, radius): ([f64; 2], f64),
) -> crate::Result<()> {
    use diffphys_report::chart::{heatmap_panels_svg, HeatmapPanels, Outline};
    let mut fields = Vec::new();
    for (name, s) in states {
        fields.push((*name, vorticity(scene, s.ux.view(), s.uy.view())?));
    }
    if fields.is_empty() {
        return Ok(());
    }
    let g = scene.grid();
    // Vorticity lives on the inner nodes: index k is the node at (k + 1) h,
    // drawn as the square [k, k + 1].
    let outline = Outline {
        centre: (centre[0] / g.dx - 0.5, centre[1] / g.dy - 0.5),
        radius: radius / g.dx,
    };
    let panels: Vec<(&str, ndarray::ArrayView2<'_, f64>)> =
        fields.iter().map(|(n, w)| (*n, w.view())).collect();
    heatmap_panels_svg(
        path,
        &HeatmapPanels {
            title,
            panels: &panels,
            axes: ["x (streamwise, node)", "y (node)"],
            outline: Some(outline),
            columns: 2,
        },
    )
    .map_err(|e| crate::HybridError::Learn(e.into()))
}
