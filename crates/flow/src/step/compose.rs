//! The step composed of the operators, written once over an executor that
//! records them on a tape or runs their forwards directly.

use std::sync::Arc;

use diffphys_tape::{ArrayD, Op, Real, Tape, Var};

use super::{Scene, Splitting};
use crate::advection::{AdvectScalar, AdvectVelocity};
use crate::boundaries::EnforceBoundaries;
use crate::diffusion::Diffuse;
use crate::forcing::{Buoyant, Forced};
use crate::immersed::{
    ConsistentForcing, ForcingImpulse, ForcingScheme, ImmersedForcing, MultiDirectForcing,
};
use crate::pressure::{Project, SolveCounter, SubtractPressureGradient};
use crate::{FlowError, Result};

/// The state as the executor's values.
pub(super) struct StateOf<V> {
    pub(super) ux: V,
    pub(super) uy: V,
    pub(super) pressure: V,
    pub(super) scalars: Vec<V>,
}

/// The parameters as the executor's values.
pub(super) struct ParamsOf<V> {
    pub(super) viscosity: V,
    pub(super) wall_speed: V,
    pub(super) inflow: V,
    /// The immersed body's shape `(c_x, c_y, r)`, on a scene with one.
    pub(super) body: Option<V>,
}

/// Runs ops: recorded on a tape, or their forwards directly.
pub trait Exec<T: Real> {
    /// A value: a tape variable, or an array.
    type V: Clone;
    /// `op` applied to `inputs`.
    ///
    /// # Errors
    /// The op's error, as a [`FlowError`].
    fn run<O: Op<T> + 'static>(&self, op: O, inputs: &[&Self::V]) -> Result<Vec<Self::V>>;

    /// `values` are no longer used by the step: the plain forward gives
    /// their buffers back to the current pool (the next op's outputs take
    /// them), a tape keeps its variables.
    fn release(&self, values: Vec<Self::V>) {
        drop(values);
    }
}

/// Records on a tape.
pub(super) struct OnTape<'t, T: Real>(pub(super) &'t Tape<T>);

impl<'t, T: Real> Exec<T> for OnTape<'t, T> {
    type V = Var<'t, T>;
    fn run<O: Op<T> + 'static>(&self, op: O, inputs: &[&Var<'t, T>]) -> Result<Vec<Var<'t, T>>> {
        let vars: Vec<Var<'t, T>> = inputs.iter().map(|v| **v).collect();
        crate::record(self.0, op, &vars).map_err(FlowError::from_tape)
    }
}

/// Runs the forwards without a tape.
pub(super) struct Plain;

impl<T: Real> Exec<T> for Plain {
    type V = ArrayD<T>;
    fn run<O: Op<T> + 'static>(&self, mut op: O, inputs: &[&ArrayD<T>]) -> Result<Vec<ArrayD<T>>> {
        let views: Vec<_> = inputs.iter().map(|a| a.view()).collect();
        op.forward(&views).map_err(FlowError::from_tape)
    }

    fn release(&self, values: Vec<ArrayD<T>>) {
        values
            .into_iter()
            .for_each(diffphys_tape::pool::recycle_array);
    }
}

pub(super) fn two<V>(mut v: Vec<V>) -> (V, V) {
    let b = v.pop().expect("two outputs");
    let a = v.pop().expect("two outputs");
    (a, b)
}

/// One (sub)step of `dt`: the physics, piece by piece (see the module docs).
pub(super) fn substep<T: Real, E: Exec<T>>(
    e: &E,
    scene: &Scene,
    s: StateOf<E::V>,
    p: &ParamsOf<E::V>,
    dt: f64,
    counter: &SolveCounter,
    impulse: &ForcingImpulse,
) -> Result<StateOf<E::V>> {
    let settings = scene.settings();
    let (grid, faces) = (scene.grid(), scene.faces());
    let (ux, uy) = if faces.all_free() {
        (s.ux, s.uy)
    } else {
        two(e.run(
            EnforceBoundaries {
                grid: grid.clone(),
                faces: Arc::clone(faces),
            },
            &[&s.ux, &s.uy, &p.inflow],
        )?)
    };
    let advect = AdvectScalar {
        grid: grid.clone(),
        faces: Arc::clone(faces),
        scheme: settings.advection,
        dt,
    };
    let scalars = s
        .scalars
        .iter()
        .map(|q| {
            Ok(e.run(advect.clone(), &[q, &ux, &uy, &p.wall_speed])?
                .remove(0))
        })
        .collect::<Result<Vec<_>>>()?;
    let incremental = settings.splitting == Splitting::Incremental;
    let (qx, qy) = if incremental {
        two(e.run(
            SubtractPressureGradient {
                grid: grid.clone(),
                faces: Arc::clone(faces),
                c: dt / 2.0,
            },
            &[&ux, &uy, &s.pressure],
        )?)
    } else {
        (ux.clone(), uy.clone())
    };
    let advect = AdvectVelocity {
        grid: grid.clone(),
        faces: Arc::clone(faces),
        scheme: settings.advection,
        dt,
    };
    let advected = two(e.run(advect, &[&qx, &qy, &ux, &uy, &p.wall_speed])?);
    e.release(vec![qx, qy, ux, uy]);
    let (ux, mut uy) = advected;
    if let Some(b) = scene.0.buoyancy {
        uy = e
            .run(
                Buoyant {
                    grid: grid.clone(),
                    faces: Arc::clone(faces),
                    beta: b.beta,
                    dt,
                },
                &[&uy, &scalars[b.scalar]],
            )?
            .remove(0);
    }
    let (ux, uy) = match &scene.0.forcing {
        Some(forcing) => two(e.run(
            Forced {
                grid: grid.clone(),
                faces: Arc::clone(faces),
                forcing: Arc::clone(forcing),
                dt,
            },
            &[&ux, &uy],
        )?),
        None => (ux, uy),
    };
    let diffused = two(e.run(
        Diffuse {
            diffusion: Arc::clone(scene.diffusion()),
            mode: settings.viscosity_mode,
            dt,
        },
        &[&ux, &uy, &p.viscosity, &p.wall_speed],
    )?);
    e.release(vec![ux, uy]);
    let (ux, uy) = diffused;
    let tau = if incremental { dt / 2.0 } else { dt };
    let project = Project {
        system: Arc::clone(scene.pressure_system()),
        tau,
        counter: counter.clone(),
    };
    let mut out = match (&scene.0.immersed, &p.body, scene.0.immersed_scheme) {
        (Some(body), Some(shape), ForcingScheme::Direct) => {
            let (ux, uy) = two(e.run(
                ImmersedForcing {
                    body: Arc::clone(body),
                    impulse: impulse.clone(),
                },
                &[&ux, &uy, shape],
            )?);
            e.run(project, &[&ux, &uy, &s.pressure])?
        }
        (Some(body), Some(shape), ForcingScheme::ProjectionConsistent) => {
            let (ux, uy) = two(e.run(
                ConsistentForcing {
                    body: Arc::clone(body),
                    faces: Arc::clone(faces),
                    tau,
                    impulse: impulse.clone(),
                },
                &[&ux, &uy, &s.pressure, shape],
            )?);
            e.run(project, &[&ux, &uy, &s.pressure])?
        }
        // the forcing and the projection alternated, as one op
        (Some(body), Some(shape), scheme @ ForcingScheme::MultiDirect { .. }) => e.run(
            MultiDirectForcing {
                body: Arc::clone(body),
                system: Arc::clone(scene.pressure_system()),
                tau,
                passes: MultiDirectForcing::passes_of(scheme),
                impulse: impulse.clone(),
                counter: counter.clone(),
            },
            &[&ux, &uy, &s.pressure, shape],
        )?,
        _ => e.run(project, &[&ux, &uy, &s.pressure])?,
    };
    let pressure = out.pop().expect("three outputs");
    let projected = two(out);
    e.release(vec![ux, uy, s.pressure]);
    let (ux, uy) = projected;
    Ok(StateOf {
        ux,
        uy,
        pressure,
        scalars,
    })
}
