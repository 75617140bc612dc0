//! Batches of flow states as one array, for learning libraries that step a
//! batch `[batch, …]` (diffphys-learn's `Simulator`), and the restriction of a
//! velocity to a coarser grid by face averages.
//!
//! **Packed layout.** One sample is `[2, nx + 1, ny + 1]`
//! ([`Scene::packed_shape`]): channel 0 holds `u_x` in its top-left
//! [`FlowGrid::shape_x`](crate::FlowGrid::shape_x) block, channel 1 holds `u_y`
//! in its [`FlowGrid::shape_y`](crate::FlowGrid::shape_y) block, every other
//! entry is zero except the corner `[1, nx, ny]` (never part of `u_y`, whose
//! first axis has `nx` entries), which carries the sample's viscosity `ν`. So a
//! batch can mix Reynolds numbers, and a network reads the velocity as two
//! channels on one `(nx + 1) × (ny + 1)` lattice.
//!
//! The layout carries no pressure: every packed step starts its pressure solve
//! from `P = 0`, which is exact only with [`Splitting::Plain`] (the state's
//! pressure is then a warm start and nothing else), so the packed steps require
//! it. Scalars are not carried either (scenes with scalars are refused).
//!
//! **Gradients.** [`Scene::step_packed`] records one [`Scene::step`] per
//! sample, so gradients reach the velocity entries exactly as through the
//! step; the viscosity entry is read as data (no gradient flows to it) and the
//! zero entries stay zero.
//!
//! **Restriction.** [`restrict_velocity`] averages the fine faces that tile
//! each coarse face: `U_x[i, j] = (1/r) Σ_k u_x[r i, r j + k]` and the same
//! along y. The flux through every coarse face is the fine flux through it, so
//! the coarse divergence is the average of the fine divergence over each block
//! of `r × r` cells: a divergence-free fine field stays divergence-free.

use diffphys_tape::{ArrayD, Real, Var};
use ndarray::{s, Array2, Array3, ArrayView2, ArrayView3, ArrayViewD, Axis, Ix3};

use crate::step::Splitting;
use crate::{FlowError, FlowGrid, FlowParams, FlowState, FlowVars, ParamVars, Result, Scene};

const STEP: &str = "packed flow step";

impl Scene {
    /// The shape of one packed sample, `[2, nx + 1, ny + 1]` (see the
    /// [module docs](crate::packed)).
    pub fn packed_shape(&self) -> [usize; 3] {
        let g = self.grid();
        [2, g.nx + 1, g.ny + 1]
    }

    /// The velocity of `state` and the viscosity `nu` as one packed sample
    /// (the pressure and scalars are dropped).
    ///
    /// # Errors
    /// [`FlowError::Shape`] for a velocity of the wrong shape.
    pub fn pack<T: Real>(&self, state: &FlowState<T>, nu: T) -> Result<Array3<T>> {
        self.grid()
            .check_velocity(STEP, state.ux.view(), state.uy.view())?;
        let [c, a, b] = self.packed_shape();
        let mut out = Array3::zeros((c, a, b));
        let [x0, x1] = self.grid().shape_x();
        let [y0, y1] = self.grid().shape_y();
        out.slice_mut(s![0, ..x0, ..x1]).assign(&state.ux);
        out.slice_mut(s![1, ..y0, ..y1]).assign(&state.uy);
        out[[1, a - 1, b - 1]] = nu;
        Ok(out)
    }

    /// The state (pressure zero) and the viscosity of one packed sample.
    ///
    /// # Errors
    /// [`FlowError::Shape`] for a sample of another shape than
    /// [`Scene::packed_shape`].
    pub fn unpack<T: Real>(&self, sample: ArrayView3<'_, T>) -> Result<(FlowState<T>, T)> {
        let shape = self.packed_shape();
        if sample.shape() != shape {
            return Err(FlowError::shape(
                STEP,
                "packed sample",
                &shape,
                sample.shape(),
            ));
        }
        let [x0, x1] = self.grid().shape_x();
        let [y0, y1] = self.grid().shape_y();
        let ux = sample.slice(s![0, ..x0, ..x1]).to_owned();
        let uy = sample.slice(s![1, ..y0, ..y1]).to_owned();
        let nu = sample[[1, shape[1] - 1, shape[2] - 1]];
        Ok((FlowState::from_velocity(self, ux, uy), nu))
    }

    /// Checks that the scene can be stepped packed and reads the batch size of
    /// `shape`.
    fn packed_batch(&self, shape: &[usize]) -> Result<usize> {
        if self.settings().splitting != Splitting::Plain {
            return Err(FlowError::scene(
                "splitting",
                "packed states carry no pressure, so packed steps need Splitting::Plain",
            ));
        }
        if self.scalars() != 0 {
            return Err(FlowError::scene(
                "scalars",
                "packed states carry no passive scalars",
            ));
        }
        let [c, a, b] = self.packed_shape();
        match *shape {
            [n, cc, aa, bb] if (cc, aa, bb) == (c, a, b) => Ok(n),
            _ => {
                let n = shape.first().copied().unwrap_or(0);
                Err(FlowError::shape(STEP, "packed batch", &[n, c, a, b], shape))
            }
        }
    }

    /// One step of every sample of the packed batch `state`
    /// (`[batch, 2, nx + 1, ny + 1]`), each at its own viscosity, recorded on
    /// the batch's tape (see the [module docs](crate::packed)). The scene's
    /// inflow profile and wall speeds apply to every sample.
    ///
    /// # Errors
    /// [`FlowError::InvalidScene`] unless the scene uses [`Splitting::Plain`]
    /// and has no scalars; [`FlowError::Shape`] for a batch of another shape;
    /// whatever [`Scene::step`] returns.
    pub fn step_packed<'t, T: Real>(&self, state: Var<'t, T>) -> Result<Var<'t, T>> {
        let batch = self.packed_batch(&state.shape())?;
        let tape = state.tape();
        let [_, a, b] = self.packed_shape();
        let g = self.grid();
        let ([x0, x1], [y0, y1]) = (g.shape_x(), g.shape_y());
        let values = state.to_array();
        let params = self.params::<T>();
        let zeros = tape.constant(ArrayD::zeros(g.cell_shape().to_vec()));
        let t = FlowError::from_tape;
        let mut samples = Vec::with_capacity(batch);
        for n in 0..batch {
            let nu = values[[n, 1, a - 1, b - 1]];
            let one = state.slice(0, n, n + 1).map_err(t)?;
            let component = |c: usize, rows: usize, cols: usize| {
                one.slice(1, c, c + 1)?
                    .slice(2, 0, rows)?
                    .slice(3, 0, cols)?
                    .reshape(&[rows, cols])
            };
            let vars = FlowVars {
                ux: component(0, x0, x1).map_err(t)?,
                uy: component(1, y0, y1).map_err(t)?,
                pressure: zeros,
                scalars: Vec::new(),
            };
            let p = ParamVars::constants(
                tape,
                &FlowParams {
                    viscosity: nu,
                    ..params.clone()
                },
            );
            let (next, _) = self.step(tape, &vars, &p)?;
            let place = |v: Var<'t, T>, rows: usize, cols: usize| {
                v.reshape(&[1, 1, rows, cols])?
                    .pad(2, 0, a - rows)?
                    .pad(3, 0, b - cols)
            };
            let mut corner = ArrayD::zeros(vec![1, 2, a, b]);
            corner[[0, 1, a - 1, b - 1]] = nu;
            let sample = Var::concat(
                &[
                    place(next.ux, x0, x1).map_err(t)?,
                    place(next.uy, y0, y1).map_err(t)?,
                ],
                1,
            )
            .and_then(|v| v.add(tape.constant(corner)))
            .map_err(t)?;
            samples.push(sample);
        }
        Var::concat(&samples, 0).map_err(t)
    }

    /// [`Scene::step_packed`] without a tape: [`Scene::forward`] of every
    /// sample.
    ///
    /// # Errors
    /// As [`Scene::step_packed`].
    pub fn forward_packed<T: Real>(&self, state: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        self.packed_batch(state.shape())?;
        let params = self.params::<T>();
        let mut out = ArrayD::zeros(state.shape());
        for (sample, mut dst) in state.outer_iter().zip(out.outer_iter_mut()) {
            let sample = sample
                .into_dimensionality::<Ix3>()
                .map_err(|_| FlowError::shape(STEP, "packed sample", &[0, 0, 0], &[]))?;
            let (s, nu) = self.unpack(sample)?;
            let p = FlowParams {
                viscosity: nu,
                ..params.clone()
            };
            let (next, _) = self.forward(&s, &p)?;
            dst.assign(&self.pack(&next, nu)?.into_dyn());
        }
        Ok(out)
    }
}

/// The velocity `(u_x, u_y)` of the grid `r` times finer than `coarse` (same
/// domain and sides) restricted to `coarse` by face averages (see the
/// [module docs](crate::packed)).
///
/// # Errors
/// [`FlowError::InvalidParameter`] for `r = 0`; [`FlowError::Shape`] if the
/// fine velocity is not of the finer grid's shapes.
pub fn restrict_velocity<T: Real>(
    coarse: &FlowGrid,
    r: usize,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    const WHAT: &str = "velocity restriction";
    if r == 0 {
        return Err(FlowError::parameter(WHAT, "factor", "must be at least 1"));
    }
    let ([x0, x1], [y0, y1]) = (coarse.shape_x(), coarse.shape_y());
    let (px, py) = (coarse.periodic_x(), coarse.periodic_y());
    let fine_x = [r * coarse.nx + usize::from(!px), r * coarse.ny];
    let fine_y = [r * coarse.nx, r * coarse.ny + usize::from(!py)];
    if ux.shape() != fine_x {
        return Err(FlowError::shape(
            WHAT,
            "fine x-velocity",
            &fine_x,
            ux.shape(),
        ));
    }
    if uy.shape() != fine_y {
        return Err(FlowError::shape(
            WHAT,
            "fine y-velocity",
            &fine_y,
            uy.shape(),
        ));
    }
    let w = T::from_f64(1.0 / r as f64);
    let cx = Array2::from_shape_fn((x0, x1), |(i, j)| {
        ux.slice(s![r * i, r * j..r * (j + 1)]).sum() * w
    });
    let cy = Array2::from_shape_fn((y0, y1), |(i, j)| {
        uy.slice(s![r * i..r * (i + 1), r * j]).sum() * w
    });
    Ok((cx, cy))
}

/// Stacks packed samples into a batch `[batch, 2, nx + 1, ny + 1]`.
///
/// # Errors
/// [`FlowError::Shape`] without samples or for samples of different shapes.
pub fn batch_of_packed<T: Real>(samples: &[Array3<T>]) -> Result<ArrayD<T>> {
    let views: Vec<_> = samples.iter().map(|a| a.view()).collect();
    ndarray::stack(Axis(0), &views)
        .map(|a| a.into_dyn())
        .map_err(|_| FlowError::shape(STEP, "packed samples", &[], &[samples.len()]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostics::divergence;
    use crate::{Boundary, Obstacle, Sides};
    use diffphys_tape::{check_gradient, GradCheckOptions, Tape};

    fn wake(nx: usize, ny: usize) -> Scene {
        channel(nx, ny)
            .obstacle(Obstacle::cylinder([0.6, 0.5], 0.2))
            .build()
            .unwrap()
    }

    fn channel(nx: usize, ny: usize) -> crate::SceneBuilder {
        Scene::builder(nx, ny, [2.0, 1.0])
            .sides(Sides {
                left: Boundary::Inflow,
                right: Boundary::Outflow,
                bottom: Boundary::FreeSlip,
                top: Boundary::FreeSlip,
            })
            .uniform_inflow(1.0)
            .viscosity(0.01)
            .dt(0.02)
            .splitting(Splitting::Plain)
    }

    fn state(scene: &Scene, seed: u64) -> FlowState<f64> {
        let g = scene.grid();
        let wobble = |a: usize, b: usize, k: f64| {
            1.0 + 0.3 * ((a as f64 * 0.7 + b as f64 * 1.3 + k + seed as f64).sin())
        };
        let ux = Array2::from_shape_fn(g.shape_x(), |(a, b)| wobble(a, b, 0.0));
        let uy = Array2::from_shape_fn(g.shape_y(), |(a, b)| 0.2 * wobble(a, b, 2.0) - 0.2);
        FlowState::from_velocity(scene, ux, uy)
    }

    #[test]
    fn pack_and_unpack_round_trip() {
        let scene = wake(12, 6);
        let s = state(&scene, 1);
        let p = scene.pack(&s, 0.003).unwrap();
        assert_eq!(p.shape(), &[2, 13, 7]);
        let (back, nu) = scene.unpack(p.view()).unwrap();
        assert_eq!(back.ux, s.ux);
        assert_eq!(back.uy, s.uy);
        assert_eq!(nu, 0.003);
        let wrong = Array3::<f64>::zeros((2, 12, 7));
        assert!(matches!(
            scene.unpack(wrong.view()),
            Err(FlowError::Shape { .. })
        ));
    }

    #[test]
    fn packed_steps_match_the_step_of_each_sample() {
        let scene = wake(12, 6);
        let nus = [0.01, 0.004];
        let samples: Vec<_> = nus
            .iter()
            .enumerate()
            .map(|(k, &nu)| scene.pack(&state(&scene, k as u64), nu).unwrap())
            .collect();
        let batch = batch_of_packed(&samples).unwrap();
        let plain = scene.forward_packed(batch.view()).unwrap();
        let tape = Tape::new();
        let taped = scene
            .step_packed(tape.constant(batch.clone()))
            .unwrap()
            .to_array();
        for (k, &nu) in nus.iter().enumerate() {
            let p = FlowParams {
                viscosity: nu,
                ..scene.params()
            };
            let (next, _) = scene.forward(&state(&scene, k as u64), &p).unwrap();
            let expect = scene.pack(&next, nu).unwrap().into_dyn();
            for got in [&plain, &taped] {
                let got = got.index_axis(Axis(0), k);
                let diff = (&got - &expect)
                    .mapv(f64::abs)
                    .fold(0.0, |m: f64, &v| m.max(v));
                assert!(diff < 1e-12, "sample {k}: {diff}");
            }
        }
    }

    #[test]
    fn packed_step_gradient_matches_finite_differences() {
        let scene = wake(12, 6);
        let samples: Vec<_> = [0.02, 0.01]
            .iter()
            .enumerate()
            .map(|(k, &nu)| scene.pack(&state(&scene, k as u64), nu).unwrap())
            .collect();
        let batch = batch_of_packed(&samples).unwrap();
        // The viscosity entries are data (no gradient reaches them): they
        // enter as a constant, the velocity masked to zero there.
        let mut nu = ArrayD::zeros(batch.shape());
        let mut mask = ArrayD::ones(batch.shape());
        for k in 0..2 {
            nu[[k, 1, 12, 6]] = batch[[k, 1, 12, 6]];
            mask[[k, 1, 12, 6]] = 0.0;
        }
        let velocity = &batch * &mask;
        let report = check_gradient(
            |tape, v| {
                let s = v[0]
                    .mul(tape.constant(mask.clone()))?
                    .add(tape.constant(nu.clone()))?;
                let next = scene
                    .step_packed(s)
                    .map_err(diffphys_tape::TapeError::from)?;
                next.powi(2)?.sum()
            },
            &[velocity],
            GradCheckOptions::for_type::<f64>(),
        )
        .unwrap();
        assert!(report.passed, "{report:?}");
    }

    #[test]
    fn packed_steps_need_plain_splitting_and_the_packed_shape() {
        let incremental = Scene::builder(6, 4, [2.0, 1.0])
            .sides(Sides::channel())
            .uniform_inflow(1.0)
            .build()
            .unwrap();
        let z = ArrayD::<f64>::zeros(vec![1, 2, 7, 5]);
        assert!(matches!(
            incremental.forward_packed(z.view()),
            Err(FlowError::InvalidScene { .. })
        ));
        let scene = wake(12, 6);
        let wrong = ArrayD::<f64>::zeros(vec![1, 2, 12, 7]);
        assert!(matches!(
            scene.forward_packed(wrong.view()),
            Err(FlowError::Shape { .. })
        ));
    }

    #[test]
    fn restriction_averages_the_divergence_over_blocks() {
        // Without an obstacle: the divergence of every cell is the raw D u.
        let coarse = channel(6, 4).build().unwrap();
        let fine = channel(18, 12).build().unwrap();
        let s = state(&fine, 3);
        let (ux, uy) = restrict_velocity(coarse.grid(), 3, s.ux.view(), s.uy.view()).unwrap();
        let dc = divergence(&coarse, ux.view(), uy.view()).unwrap();
        let df = divergence(&fine, s.ux.view(), s.uy.view()).unwrap();
        for ((i, j), &d) in dc.indexed_iter() {
            let block = df.slice(s![3 * i..3 * i + 3, 3 * j..3 * j + 3]).sum() / 9.0;
            // Each divergence is D u with u scaled by 1/h: compare relative to it.
            assert!((d - block).abs() < 1e-10 * (1.0 + block.abs()), "{i},{j}");
        }
        assert!(matches!(
            restrict_velocity(coarse.grid(), 2, s.ux.view(), s.uy.view()),
            Err(FlowError::Shape { .. })
        ));
    }
}
