//! A flow scene as the learning library's simulator.

use diffphys_flow::{FlowState, Scene};
use diffphys_learn::{standard_normal, Simulator, State, StateVars, Trajectory};
use diffphys_tape::{ArrayD, TapeError, Var};
use ndarray::{s, Axis};
use rand::rngs::StdRng;

use crate::{HybridError, Result};

/// One velocity component after a step, the target's, and the free-face
/// mask of its block of the lattice.
type Compared<'a> = (ArrayD<f64>, &'a ArrayD<f64>, ndarray::ArrayViewD<'a, f64>);

/// `scene`'s step as a [`Simulator`]: one step of a batch of states as
/// fields (`u_x [B, ..]`, `u_y [B, ..]`, and the pressure when the scheme
/// carries it, the simulator's auxiliary field: [`diffphys_flow::batch`]),
/// each sample at its own viscosity (the state's one parameter, `[B]`).
///
/// Forward and adjoint are the scene's ([`Scene::forward_batch`],
/// [`Scene::step_batch`]): gradients reach every field and each sample's
/// viscosity. Input noise ([`Simulator::perturb`]) is drawn on the corrector's
/// face lattice ([`free_faces`]), one normal number per lattice entry in
/// order, and added where the lattice holds a free face: walls, the inflow and
/// the body keep their values.
#[derive(Debug, Clone)]
pub struct FlowSimulator {
    scene: Scene,
    free: ArrayD<f64>,
}

impl FlowSimulator {
    /// The simulator of `scene`.
    pub fn new(scene: Scene) -> Self {
        let free = free_faces(&scene);
        FlowSimulator { scene, free }
    }

    /// The scene it steps.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The faces a correction may change, on the face lattice
    /// ([`free_faces`]).
    pub fn free(&self) -> &ArrayD<f64> {
        &self.free
    }

    /// One sample of this simulator's state ([`sample`]).
    pub fn sample(&self, state: &FlowState<f64>, nu: f64) -> State {
        sample(&self.scene, state, nu)
    }

    /// One plain step of the one sample `now`: each velocity component's
    /// new values beside `then`'s and the free-face mask of its block of the
    /// lattice.
    fn compare_step<'a>(&'a self, now: &State, then: &'a State) -> Result<Vec<Compared<'a>>> {
        let next = self.step_plain(&State::stack(&[now])?)?;
        Ok(next
            .into_iter()
            .zip(&then.fields)
            .take(2)
            .enumerate()
            .map(|(c, (p, r))| {
                let (a, b) = (r.shape()[0], r.shape()[1]);
                let p = p.index_axis_move(Axis(0), 0);
                (p, r, self.free.slice(s![c, ..a, ..b]).into_dyn())
            })
            .collect())
    }

    /// The root mean square one-step error over the free faces, from every
    /// `stride`-th state of `trajectories` to the next: the scale of input
    /// noise that resembles the solver's own error.
    ///
    /// # Errors
    /// [`HybridError::Trajectory`] for no pair of states or a zero stride; a
    /// step that fails.
    pub fn one_step_rms(&self, trajectories: &[Trajectory], stride: usize) -> Result<f64> {
        let free_count: f64 = self.free.sum();
        let (mut sum, mut count) = (0.0, 0.0);
        if stride == 0 {
            return Err(HybridError::Trajectory {
                what: "one-step error",
                message: "a stride of 0".into(),
            });
        }
        for tr in trajectories {
            for t in (0..tr.len().saturating_sub(1)).step_by(stride) {
                for (p, r, mask) in self.compare_step(&tr[t], &tr[t + 1])? {
                    let d = (&p - r) * &mask;
                    sum += d.mapv(|e| e * e).sum();
                }
                count += free_count;
            }
        }
        if count == 0.0 {
            return Err(HybridError::Trajectory {
                what: "one-step error",
                message: "no trajectory holds two states".into(),
            });
        }
        Ok((sum / count).sqrt())
    }

    /// The error no correction can remove: the relative L2 norm, on the faces
    /// the step pins (inflow, walls, solid cells), of one step from each state
    /// of `trajectory` against the next, mean over the steps. Zero when every
    /// pinned face of the reference holds what the solver pins there; a
    /// corrector only changes the free faces, so the rollout error of any
    /// corrected solver is at least about this.
    ///
    /// # Errors
    /// A step that fails.
    pub fn pinned_face_error(&self, trajectory: &[State]) -> Result<f64> {
        let mut sum = 0.0;
        for pair in trajectory.windows(2) {
            let (mut pinned, mut norm) = (0.0, 0.0);
            for (p, r, mask) in self.compare_step(&pair[0], &pair[1])? {
                for ((p, r), m) in p.iter().zip(r.iter()).zip(mask.iter()) {
                    if *m == 0.0 {
                        pinned += (p - r).powi(2);
                    }
                    norm += r * r;
                }
            }
            sum += (pinned / norm).sqrt();
        }
        Ok(sum / trajectory.len().saturating_sub(1).max(1) as f64)
    }
}

/// One sample of a [`FlowSimulator`]'s state on `scene`: the fields the
/// scene carries of `state` ([`Scene::sample_of`]), with the viscosity `nu`
/// as its parameter.
pub fn sample(scene: &Scene, state: &FlowState<f64>, nu: f64) -> State {
    State::new(scene.sample_of(state), vec![ndarray::arr0(nu).into_dyn()])
}

/// The viscosities of a batch: its one parameter.
fn viscosities<T>(params: &[T]) -> diffphys_tape::Result<&T> {
    params.first().ok_or_else(|| {
        TapeError::invalid(
            "flow simulator",
            "no viscosity among the state's parameters",
        )
    })
}

impl Simulator for FlowSimulator {
    fn auxiliary_fields(&self) -> usize {
        self.scene.batch_fields() - 2
    }

    fn step<'t>(&self, state: &StateVars<'t>) -> diffphys_tape::Result<Vec<Var<'t, f64>>> {
        Ok(self
            .scene
            .step_batch(&state.fields, *viscosities(&state.params)?)?)
    }

    fn step_plain(&self, state: &State) -> diffphys_tape::Result<Vec<ArrayD<f64>>> {
        let fields: Vec<_> = state.fields.iter().map(|f| f.view()).collect();
        Ok(self
            .scene
            .forward_batch(&fields, viscosities(&state.params)?.view())?)
    }

    /// Nothing is drawn for a state that is not a batch of velocity fields
    /// (`[B, .., ..]` each): the trainer refuses such a state before it
    /// perturbs one ([`diffphys_learn::Hybrid::check_shapes`]).
    fn perturb(&self, state: &mut State, sigma: f64, rng: &mut StdRng) {
        let pair = &state.fields[..state.fields.len().min(2)];
        if pair.len() < 2
            || pair.iter().any(|f| f.ndim() != 3)
            || pair[0].shape()[0] != pair[1].shape()[0]
        {
            return;
        }
        let (a, b) = (self.free.shape()[1], self.free.shape()[2]);
        let (ux, rest) = state.fields.split_at_mut(1);
        let (ux, uy) = (&mut ux[0], &mut rest[0]);
        for n in 0..ux.shape()[0] {
            for (c, field) in [&mut *ux, &mut *uy].into_iter().enumerate() {
                let shape = [field.shape()[1], field.shape()[2]];
                for i in 0..a {
                    for j in 0..b {
                        let noise = sigma * standard_normal(rng);
                        if i < shape[0] && j < shape[1] {
                            field[[n, i, j]] += self.free[[c, i, j]] * noise;
                        }
                    }
                }
            }
        }
    }
}

/// The faces a correction may change, on the face lattice `[2, nx + 1, ny + 1]`
/// (`u_x` in the top-left `[nx + 1, ny]` of channel 0, `u_y` in the top-left
/// `[nx, ny + 1]` of channel 1; a periodic axis uses its first `nx` or `ny`
/// rows): 1 on a face between two fluid cells, 0 on the padding, the
/// domain's boundary faces (inflow, outflow, walls) and the faces of solid
/// cells.
pub fn free_faces(scene: &Scene) -> ArrayD<f64> {
    let g = scene.grid();
    let solid = scene.solid();
    let (nx, ny) = (g.nx, g.ny);
    let is_solid = |i: Option<usize>, j: Option<usize>| match (i, j) {
        (Some(i), Some(j)) if i < nx && j < ny => solid[[i, j]],
        _ => false,
    };
    let mut m = ArrayD::zeros(vec![2, nx + 1, ny + 1]);
    for a in 1..=nx {
        for b in 0..ny {
            let fixed = is_solid(a.checked_sub(1), Some(b)) || is_solid(Some(a), Some(b));
            m[[0, a, b]] = f64::from(u8::from(!fixed));
        }
    }
    for a in 0..nx {
        for b in 1..ny {
            let fixed = is_solid(Some(a), b.checked_sub(1)) || is_solid(Some(a), Some(b));
            m[[1, a, b]] = f64::from(u8::from(!fixed));
        }
    }
    m
}
