//! The forces on the DFG cylinder: the surface integral over the staircase,
//! the momentum exchange of an immersed body's forcing, and the momentum
//! balance over a control volume (see [`super::Dfg2d1`]).

use crate::diagnostics::{obstacle_force, ForceWeights};
use crate::{FlowState, Result, Scene, Splitting, StepInfo};

use super::{control_volume_force, DfgChannel, FaceBox, DFG_CENTRE, DFG_DIAMETER, DFG_NU};

impl DfgChannel {
    /// The force `[F_x, F_y]` of the flow on the staircase at viscosity `nu`,
    /// `F = ∮ (−p n + ν ∂u/∂n) dS` over the solid faces ([`obstacle_force`]:
    /// the pressure of the fluid cell next to each face, the wall shear
    /// `ν ū_t / (h/2)`). `nu` = [`DFG_NU`] gives the whole force, `nu = 0` its
    /// pressure part alone. Not the force on an immersed body (see
    /// [`DfgChannel::body_force`]).
    ///
    /// # Errors
    /// [`crate::FlowError::Shape`] for a state of another scene.
    pub fn force(scene: &Scene, s: &FlowState<f64>, nu: f64) -> Result<[f64; 2]> {
        let f = obstacle_force(
            scene.force_weights(),
            s.ux.view(),
            s.uy.view(),
            s.pressure.view(),
            nu,
        )?;
        Ok([f[0], f[1]])
    }

    /// The force `[F_x, F_y]` of the flow on the body at the state `s`, by
    /// the body's own method: on the staircase the surface integral
    /// ([`DfgChannel::force`] at [`DFG_NU`]); on an immersed body the
    /// momentum exchange of one step from `s` ([`DfgChannel::exchange_force`]).
    ///
    /// # Errors
    /// [`crate::FlowError::Shape`] for a state of another scene; those of
    /// [`Scene::forward`].
    pub fn body_force(scene: &Scene, s: &FlowState<f64>) -> Result<[f64; 2]> {
        if scene.immersed().is_none() {
            return Self::force(scene, s, DFG_NU);
        }
        let (next, info) = scene.forward(s, &scene.params())?;
        let f = Self::exchange_force(scene, s, &info)?;
        let Some(body) = scene.immersed() else {
            return Ok(f);
        };
        // a closed interior: the pressure on the closed faces, over the
        // projection's share τ/dt of the step
        let share = match scene.settings().splitting {
            Splitting::Incremental => 0.5,
            Splitting::Plain => 1.0,
        };
        let p = body.closed_pressure_force(next.pressure.view());
        Ok([f[0] + share * p[0], f[1] + share * p[1]])
    }

    /// The force on an immersed body over the step from `s` that reported
    /// `info`, by the momentum exchange of the immersed boundary method:
    /// minus the forcing's momentum per unit time,
    /// `F = −(1/dt) Σ_forced (u'_f − u*_f) dx dy` ([`StepInfo::immersed_force`]),
    /// and, where the circle's cells are solid
    /// ([`crate::immersed::Interior::Solid`]), the momentum the staircase
    /// takes as well: the pressure of the fluid cell next to each solid face
    /// and the viscous links into the pinned faces, on `s`
    /// ([`ForceWeights::momentum_exchange`]). It reads only the body's faces,
    /// never the control volume's edges: a second method beside
    /// [`DfgChannel::control_volume_coefficients`].
    ///
    /// # Errors
    /// [`crate::FlowError::Shape`] for a state of another scene.
    pub fn exchange_force(scene: &Scene, s: &FlowState<f64>, info: &StepInfo) -> Result<[f64; 2]> {
        let f = info.immersed_force;
        if !scene.solid().iter().any(|&c| c) {
            return Ok(f);
        }
        let weights = ForceWeights::momentum_exchange(scene.grid(), scene.solid());
        let e = obstacle_force(
            &weights,
            s.ux.view(),
            s.uy.view(),
            s.pressure.view(),
            DFG_NU,
        )?;
        Ok([f[0] + e[0], f[1] + e[1]])
    }

    /// `[cD, cL]` of a state at mean inflow `ubar`: [`DfgChannel::body_force`]
    /// over `Ubar² D / 2`.
    ///
    /// # Errors
    /// As [`DfgChannel::body_force`].
    pub fn coefficients(scene: &Scene, s: &FlowState<f64>, ubar: f64) -> Result<[f64; 2]> {
        Ok(coefficients(Self::body_force(scene, s)?, ubar))
    }

    /// The control volume of the momentum-balance forces: the square of
    /// half-width [`DfgChannel::cv_half_width`] about the cylinder's centre,
    /// its edges snapped to faces ([`FaceBox::around`]).
    pub fn control_box(&self, scene: &Scene) -> FaceBox {
        FaceBox::around(scene.grid(), DFG_CENTRE, self.cv_half_width)
    }

    /// `[cD, cL]` of a state at mean inflow `ubar` by the momentum balance
    /// over `b` ([`control_volume_force`] at [`DFG_NU`], the time term from
    /// `next`, the state one step later, or none), over `Ubar² D / 2`.
    ///
    /// # Errors
    /// Those of [`control_volume_force`]: a state of another scene, a box
    /// that leaves the domain or cuts the body.
    pub fn control_volume_coefficients(
        scene: &Scene,
        b: FaceBox,
        s: &FlowState<f64>,
        next: Option<&FlowState<f64>>,
        ubar: f64,
    ) -> Result<[f64; 2]> {
        let f = control_volume_force(scene, b, s, next, DFG_NU)?.total();
        Ok(coefficients(f, ubar))
    }
}

/// `2 F / (Ubar² D)`.
pub(super) fn coefficients(f: [f64; 2], ubar: f64) -> [f64; 2] {
    let c = 2.0 / (ubar * ubar * DFG_DIAMETER);
    [c * f[0], c * f[1]]
}
