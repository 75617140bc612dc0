//! First-order optimizers over parameter arrays and their gradients: plain gradient
//! descent and Adam.
//!
//! Parameters live outside the tape (a tape is rebuilt every iteration); an
//! optimizer updates them in place from the gradients one backward sweep returned:
//!
//! ```
//! use diffphys_tape::optim::{GradientDescent, Optimizer};
//! use diffphys_tape::{arr_dyn, Tape};
//!
//! // Minimise Σ (x − 3)²: gradient 2(x − 3), minimiser x = 3.
//! let mut params = vec![arr_dyn(&[0.0, 10.0])];
//! let mut opt = GradientDescent::new(0.25);
//! for _ in 0..50 {
//!     let tape = Tape::<f64>::new();
//!     let x = tape.var(params[0].clone());
//!     let d = x.sub(tape.scalar(3.0))?;
//!     let loss = d.mul(d)?.sum()?;
//!     let grads = tape.backward(loss, &[x])?;
//!     opt.step_vars(&mut params, &grads, &[x])?;
//! }
//! assert!(params[0].iter().all(|&v| (v - 3.0).abs() < 1e-12));
//! # Ok::<(), diffphys_tape::TapeError>(())
//! ```
//!
//! Every step checks its arguments before it changes anything: a step that returns
//! an error leaves the parameters and the optimizer's state as they were.

use ndarray::{ArrayD, ArrayViewD, Zip};

use crate::{Gradients, Real, Result, TapeError, Var};

/// An optimizer: updates parameters in place from their gradients, one step at a
/// time. Parameter `i` is updated from gradient `i`.
///
/// Implementors write [`Optimizer::step_views`]; [`Optimizer::step`] and
/// [`Optimizer::step_vars`] feed it owned arrays or a [`Gradients`] container.
pub trait Optimizer<T: Real> {
    /// A short name for error messages (`"gradient descent"`, `"adam"`).
    fn name(&self) -> &str;

    /// One update of `params` from `grads`, given as views.
    ///
    /// # Errors
    /// As [`Optimizer::step`].
    fn step_views(&mut self, params: &mut [ArrayD<T>], grads: &[ArrayViewD<'_, T>]) -> Result<()>;

    /// One update of `params` from `grads`.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] if there are not as many gradients as
    /// parameters, if a gradient holds NaN or infinity (naming the parameter), or if
    /// a hyperparameter is out of range; [`TapeError::ShapeMismatch`] if a gradient's
    /// shape differs from its parameter's (naming the parameter), or, for stateful
    /// optimizers, if the parameters' shapes changed since the first step. On error
    /// nothing is updated.
    fn step(&mut self, params: &mut [ArrayD<T>], grads: &[ArrayD<T>]) -> Result<()> {
        let views: Vec<ArrayViewD<'_, T>> = grads.iter().map(|g| g.view()).collect();
        self.step_views(params, &views)
    }

    /// One update of `params` from the gradients of a backward sweep: parameter `i`
    /// was recorded as the variable `vars[i]`, and its gradient is `grads.get(vars[i])`.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] if `vars` and `params` differ in length or a
    /// variable has no gradient in `grads` (it was not requested, or it belongs to
    /// another tape); otherwise as [`Optimizer::step`].
    fn step_vars(
        &mut self,
        params: &mut [ArrayD<T>],
        grads: &Gradients<T>,
        vars: &[Var<'_, T>],
    ) -> Result<()> {
        let views = vars
            .iter()
            .enumerate()
            .map(|(i, v)| {
                grads.get(*v).map(|g| g.view()).ok_or_else(|| {
                    TapeError::invalid(
                        self.name(),
                        format!(
                            "no gradient for parameter {i} (variable {}): it was not \
                             requested from backward, or it is on another tape",
                            v.index()
                        ),
                    )
                })
            })
            .collect::<Result<Vec<_>>>()?;
        self.step_views(params, &views)
    }
}

/// Checks counts, shapes and finiteness of a step's arguments.
fn check_step_args<T: Real>(
    name: &str,
    params: &[ArrayD<T>],
    grads: &[ArrayViewD<'_, T>],
) -> Result<()> {
    if params.len() != grads.len() {
        return Err(TapeError::invalid(
            name,
            format!("{} parameters but {} gradients", params.len(), grads.len()),
        ));
    }
    for (i, (p, g)) in params.iter().zip(grads).enumerate() {
        if p.shape() != g.shape() {
            return Err(TapeError::shape(
                &format!("{name} step, parameter {i} vs its gradient"),
                p.shape(),
                g.shape(),
            ));
        }
        let bad = g.iter().filter(|x| !x.is_finite()).count();
        if bad > 0 {
            return Err(TapeError::invalid(
                name,
                format!(
                    "the gradient of parameter {i} has {bad} non-finite entries (of {})",
                    g.len()
                ),
            ));
        }
    }
    Ok(())
}

fn check_hyper<T: Real>(name: &str, what: &str, value: T, ok: bool) -> Result<()> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(TapeError::invalid(
            name,
            format!("{what} = {value} is out of range"),
        ))
    }
}

/// Plain gradient descent: `x ← x − lr · g`.
///
/// # References
/// A. Cauchy, *Méthode générale pour la résolution des systèmes d'équations
/// simultanées*, C. R. Acad. Sci. Paris 25 (1847) 536–538.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GradientDescent<T: Real> {
    /// The learning rate (step size), finite and positive.
    pub lr: T,
}

impl<T: Real> GradientDescent<T> {
    /// Gradient descent with step size `lr` (checked at the first step).
    pub fn new(lr: T) -> Self {
        GradientDescent { lr }
    }
}

impl<T: Real> Optimizer<T> for GradientDescent<T> {
    fn name(&self) -> &str {
        "gradient descent"
    }

    fn step_views(&mut self, params: &mut [ArrayD<T>], grads: &[ArrayViewD<'_, T>]) -> Result<()> {
        check_hyper(self.name(), "lr", self.lr, self.lr > T::zero())?;
        check_step_args(self.name(), params, grads)?;
        let lr = self.lr;
        for (p, g) in params.iter_mut().zip(grads) {
            p.scaled_add(-lr, g);
        }
        Ok(())
    }
}

/// Adam: gradient descent scaled per coordinate by running moments of the gradient.
///
/// At step `t = 1, 2, …`, with gradient `g`:
///
/// ```text
/// m ← β₁ m + (1 − β₁) g            first moment (mean)
/// v ← β₂ v + (1 − β₂) g²           second moment (uncentred variance)
/// m̂ = m / (1 − β₁ᵗ),  v̂ = v / (1 − β₂ᵗ)   bias correction (m, v start at 0)
/// x ← x − lr · m̂ / (√v̂ + ε)
/// ```
///
/// Bias correction makes the first step `lr · g / (|g| + ε)`: about `lr` in every
/// coordinate whatever the gradient's scale. The moments are sized lazily at the
/// first step to the parameters' shapes, which must not change afterwards
/// ([`Adam::reset`] starts afresh).
///
/// # References
/// D. P. Kingma and J. Ba, *Adam: A Method for Stochastic Optimization*, ICLR 2015,
/// arXiv:1412.6980 (Algorithm 1).
#[derive(Debug, Clone, PartialEq)]
pub struct Adam<T: Real> {
    /// The learning rate (step size `α`), finite and positive.
    pub lr: T,
    /// Decay of the first moment `β₁`, in `[0, 1)`.
    pub beta1: T,
    /// Decay of the second moment `β₂`, in `[0, 1)`.
    pub beta2: T,
    /// Added to `√v̂` so that a zero gradient does not divide by zero; positive.
    pub eps: T,
    state: Option<AdamState<T>>,
}

#[derive(Debug, Clone, PartialEq)]
struct AdamState<T: Real> {
    /// Steps taken, `t`.
    t: usize,
    /// `β₁ᵗ` and `β₂ᵗ`, kept as running products.
    beta1_t: T,
    beta2_t: T,
    m: Vec<ArrayD<T>>,
    v: Vec<ArrayD<T>>,
}

impl<T: Real> Adam<T> {
    /// Adam with step size `lr` and the paper's defaults `β₁ = 0.9`, `β₂ = 0.999`,
    /// `ε = 1e-8`. Hyperparameters are checked at each step.
    pub fn new(lr: T) -> Self {
        Adam {
            lr,
            beta1: T::from_f64(0.9),
            beta2: T::from_f64(0.999),
            eps: T::from_f64(1e-8),
            state: None,
        }
    }

    /// Sets the moment decays `β₁` and `β₂`.
    pub fn with_betas(mut self, beta1: T, beta2: T) -> Self {
        self.beta1 = beta1;
        self.beta2 = beta2;
        self
    }

    /// Sets `ε`.
    pub fn with_eps(mut self, eps: T) -> Self {
        self.eps = eps;
        self
    }

    /// Steps taken since creation or the last [`Adam::reset`].
    pub fn steps(&self) -> usize {
        self.state.as_ref().map_or(0, |s| s.t)
    }

    /// Forgets the moments and the step count; the next step sizes them afresh.
    pub fn reset(&mut self) {
        self.state = None;
    }

    fn check_hyperparameters(&self) -> Result<()> {
        let (zero, one) = (T::zero(), T::one());
        let name = self.name();
        check_hyper(name, "lr", self.lr, self.lr > zero)?;
        check_hyper(
            name,
            "beta1",
            self.beta1,
            self.beta1 >= zero && self.beta1 < one,
        )?;
        check_hyper(
            name,
            "beta2",
            self.beta2,
            self.beta2 >= zero && self.beta2 < one,
        )?;
        check_hyper(name, "eps", self.eps, self.eps > zero)
    }
}

impl<T: Real> Optimizer<T> for Adam<T> {
    fn name(&self) -> &str {
        "adam"
    }

    fn step_views(&mut self, params: &mut [ArrayD<T>], grads: &[ArrayViewD<'_, T>]) -> Result<()> {
        self.check_hyperparameters()?;
        check_step_args(self.name(), params, grads)?;
        if let Some(state) = &self.state {
            if state.m.len() != params.len() {
                return Err(TapeError::invalid(
                    self.name(),
                    format!(
                        "the first step had {} parameters, this one has {}; call reset() \
                         to start afresh",
                        state.m.len(),
                        params.len()
                    ),
                ));
            }
            for (i, (m, p)) in state.m.iter().zip(params.iter()).enumerate() {
                if m.shape() != p.shape() {
                    return Err(TapeError::shape(
                        &format!("adam step, parameter {i} at the first step vs now"),
                        m.shape(),
                        p.shape(),
                    ));
                }
            }
        }
        let state = self.state.get_or_insert_with(|| AdamState {
            t: 0,
            beta1_t: T::one(),
            beta2_t: T::one(),
            m: params.iter().map(|p| ArrayD::zeros(p.raw_dim())).collect(),
            v: params.iter().map(|p| ArrayD::zeros(p.raw_dim())).collect(),
        });

        state.t += 1;
        state.beta1_t *= self.beta1;
        state.beta2_t *= self.beta2;
        let one = T::one();
        let (b1, b2, lr, eps) = (self.beta1, self.beta2, self.lr, self.eps);
        let correct1 = one / (one - state.beta1_t);
        let correct2 = one / (one - state.beta2_t);
        for (((p, g), m), v) in params
            .iter_mut()
            .zip(grads)
            .zip(&mut state.m)
            .zip(&mut state.v)
        {
            Zip::from(p).and(g).and(m).and(v).for_each(|x, &g, m, v| {
                *m = b1 * *m + (one - b1) * g;
                *v = b2 * *v + (one - b2) * g * g;
                let m_hat = *m * correct1;
                let v_hat = *v * correct2;
                *x -= lr * m_hat / (v_hat.sqrt() + eps);
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{test_array, Tape};
    use ndarray::IxDyn;

    /// `f(x) = ½ Σ aᵢ (xᵢ − cᵢ)²` on a tape; `∇f = a ⊙ (x − c)`, minimiser `x = c`.
    fn quadratic_grad(x: &ArrayD<f64>, a: &ArrayD<f64>, c: &ArrayD<f64>) -> ArrayD<f64> {
        let tape = Tape::new();
        let xv = tape.var(x.clone());
        let d = xv.sub(tape.constant(c.clone())).unwrap();
        let half_a = tape.constant(a.mapv(|a| 0.5 * a));
        let loss = d.mul(d).unwrap().mul(half_a).unwrap().sum().unwrap();
        let mut grads = tape.backward(loss, &[xv]).unwrap();
        grads.take(xv).unwrap()
    }

    #[test]
    fn gradient_descent_on_a_quadratic_converges_to_the_minimiser() {
        let a = arr(&[1.0, 2.0, 4.0]);
        let c = arr(&[0.5, -1.0, 3.0]);
        let mut params = vec![arr(&[5.0, 5.0, 5.0])];
        // Each coordinate contracts by |1 − lr·aᵢ| ≤ 0.8 per step: 0.8²⁰⁰ ≈ 4e-20.
        let mut opt = GradientDescent::new(0.2);
        for _ in 0..200 {
            let g = quadratic_grad(&params[0], &a, &c);
            opt.step(&mut params, &[g]).unwrap();
        }
        for (x, c) in params[0].iter().zip(&c) {
            assert!((x - c).abs() < 1e-12, "{x} vs minimiser {c}");
        }
    }

    #[test]
    fn gradient_descent_step_is_x_minus_lr_g() {
        let mut params = vec![arr(&[1.0, -2.0])];
        GradientDescent::new(0.5)
            .step(&mut params, &[arr(&[4.0, 1.0])])
            .unwrap();
        // 1 − 0.5·4 = −1, −2 − 0.5·1 = −2.5
        assert_eq!(params[0], arr(&[-1.0, -2.5]));
    }

    #[test]
    fn step_vars_reads_gradients_by_variable() {
        let a = arr(&[1.0, 3.0]);
        let c = arr(&[2.0, -1.0]);
        let mut params = vec![arr(&[0.0, 0.0]), arr(&[7.0])];
        let tape = Tape::new();
        let x = tape.var(params[0].clone());
        let y = tape.var(params[1].clone());
        let d = x.sub(tape.constant(c.clone())).unwrap();
        let half_a = tape.constant(a.mapv(|a| 0.5 * a));
        // loss = ½ Σ a (x − c)² + Σ y²
        let loss = d
            .mul(d)
            .unwrap()
            .mul(half_a)
            .unwrap()
            .sum()
            .unwrap()
            .add(y.mul(y).unwrap().sum().unwrap())
            .unwrap();
        let grads = tape.backward(loss, &[x, y]).unwrap();
        GradientDescent::new(0.1)
            .step_vars(&mut params, &grads, &[x, y])
            .unwrap();
        // ∂/∂x = a(x − c) = (−2, 3) → x = (0.2, −0.3); ∂/∂y = 2y = 14 → y = 5.6
        assert!((params[0][[0]] - 0.2).abs() < 1e-15);
        assert!((params[0][[1]] + 0.3).abs() < 1e-15);
        assert!((params[1][[0]] - 5.6).abs() < 1e-15);
    }

    #[test]
    fn adam_first_step_moves_every_coordinate_by_lr() {
        // Bias correction: m̂₁ = g, v̂₁ = g², so the step is lr·g/(|g| + ε) ≈ lr·sign(g)
        // whatever the gradient's scale.
        let lr = 0.01;
        let start = arr(&[1.0, 1.0, 1.0, 1.0]);
        let g = arr(&[1e-3, -2.0, 50.0, -1e4]);
        let mut params = vec![start.clone()];
        let mut opt = Adam::new(lr);
        opt.step(&mut params, std::slice::from_ref(&g)).unwrap();
        assert_eq!(opt.steps(), 1);
        for ((x, x0), g) in params[0].iter().zip(&start).zip(&g) {
            let expected = lr * g / (g.abs() + 1e-8);
            assert!(
                (x0 - x - expected).abs() < 1e-15,
                "{x0} − {x} vs {expected}"
            );
            assert!(((x0 - x).abs() - lr).abs() < lr * 1e-5);
        }
    }

    #[test]
    fn adam_second_step_matches_algorithm_1() {
        let (lr, b1, b2, eps) = (0.1, 0.5, 0.75, 1e-3);
        let mut params = vec![arr(&[0.0])];
        let mut opt = Adam::new(lr).with_betas(b1, b2).with_eps(eps);
        opt.step(&mut params, &[arr(&[2.0])]).unwrap();
        opt.step(&mut params, &[arr(&[-1.0])]).unwrap();
        // m₁ = 0.5·2 = 1, v₁ = 0.25·4 = 1; x₁ = −0.1·(1/0.5)/(√(1/0.25) + ε)
        let x1 = -lr * (1.0 / 0.5) / ((1.0f64 / 0.25).sqrt() + eps);
        // m₂ = 0.5·1 + 0.5·(−1) = 0, so the second step does not move x.
        assert!((params[0][[0]] - x1).abs() < 1e-15);
        opt.step(&mut params, &[arr(&[4.0])]).unwrap();
        // m₃ = 0.5·0 + 0.5·4 = 2, v₂ = 0.75·1 + 0.25·1 = 1, v₃ = 0.75·1 + 0.25·16 = 4.75
        let m_hat = 2.0 / (1.0 - b1 * b1 * b1);
        let v_hat = 4.75 / (1.0 - b2 * b2 * b2);
        let x3 = x1 - lr * m_hat / (f64::sqrt(v_hat) + eps);
        assert!((params[0][[0]] - x3).abs() < 1e-15);
        assert_eq!(opt.steps(), 3);
    }

    #[test]
    fn adam_converges_on_an_ill_conditioned_quadratic() {
        let a = arr(&[1e-2, 1.0, 1e2]);
        let c = arr(&[0.5, -1.0, 3.0]);
        let mut params = vec![arr(&[0.0, 0.0, 0.0])];
        let mut opt = Adam::new(0.05);
        for _ in 0..3000 {
            let g = quadratic_grad(&params[0], &a, &c);
            opt.step(&mut params, &[g]).unwrap();
        }
        // Curvatures 1e-2 to 1e2 barely matter to Adam's per-coordinate scaling; on
        // this deterministic problem it settles on the minimiser to rounding.
        for (x, c) in params[0].iter().zip(&c) {
            assert!((x - c).abs() < 1e-9, "{x} vs minimiser {c}");
        }
    }

    #[test]
    fn optimizers_run_in_f32() {
        let mut params = vec![test_array::<f32>(&[2, 3], 1)];
        let g = test_array::<f32>(&[2, 3], 2);
        let before = params[0].clone();
        Adam::new(0.1f32)
            .step(&mut params, std::slice::from_ref(&g))
            .unwrap();
        for ((x, x0), g) in params[0].iter().zip(&before).zip(&g) {
            assert!(((x0 - x) - 0.1 * g.signum()).abs() < 1e-5);
        }
        GradientDescent::new(1.0f32)
            .step(&mut params, &[g])
            .unwrap();
    }

    #[test]
    fn count_shape_and_non_finite_errors_name_the_parameter_and_change_nothing() {
        let mut params = vec![arr(&[1.0, 2.0]), arr(&[3.0])];
        let original = params.clone();
        let mut gd = GradientDescent::new(0.1);
        let mut adam = Adam::new(0.1);
        for opt in [&mut gd as &mut dyn Optimizer<f64>, &mut adam] {
            let err = opt.step(&mut params, &[arr(&[1.0, 1.0])]).unwrap_err();
            assert!(
                err.to_string().contains("2 parameters but 1 gradients"),
                "{err}"
            );

            let err = opt
                .step(&mut params, &[arr(&[1.0, 1.0]), arr(&[1.0, 1.0])])
                .unwrap_err();
            assert!(matches!(err, TapeError::ShapeMismatch { .. }), "{err}");
            assert!(err.to_string().contains("parameter 1"), "{err}");

            let err = opt
                .step(&mut params, &[arr(&[1.0, 1.0]), arr(&[f64::NAN])])
                .unwrap_err();
            assert!(matches!(err, TapeError::InvalidArgument { .. }), "{err}");
            assert!(
                err.to_string()
                    .contains("gradient of parameter 1 has 1 non-finite"),
                "{err}"
            );
            let err = opt
                .step(&mut params, &[arr(&[f64::INFINITY, 0.0]), arr(&[1.0])])
                .unwrap_err();
            assert!(err.to_string().contains("parameter 0"), "{err}");
        }
        assert_eq!(params, original);
        assert_eq!(adam.steps(), 0, "a failed step must not advance Adam");
    }

    #[test]
    fn adam_rejects_parameters_that_change_shape_until_reset() {
        let mut opt = Adam::new(0.1);
        let mut params = vec![arr(&[1.0, 2.0])];
        opt.step(&mut params, &[arr(&[1.0, 1.0])]).unwrap();

        let mut grown = vec![arr(&[1.0, 2.0, 3.0])];
        let err = opt.step(&mut grown, &[arr(&[1.0, 1.0, 1.0])]).unwrap_err();
        assert!(matches!(err, TapeError::ShapeMismatch { .. }), "{err}");
        assert!(
            err.to_string().contains("parameter 0 at the first step"),
            "{err}"
        );
        assert_eq!(grown[0], arr(&[1.0, 2.0, 3.0]));

        let mut more = vec![arr(&[1.0, 2.0]), arr(&[0.0])];
        let err = opt
            .step(&mut more, &[arr(&[1.0, 1.0]), arr(&[1.0])])
            .unwrap_err();
        assert!(
            err.to_string().contains("the first step had 1 parameters"),
            "{err}"
        );

        opt.reset();
        assert_eq!(opt.steps(), 0);
        opt.step(&mut grown, &[arr(&[1.0, 1.0, 1.0])]).unwrap();
        assert_eq!(opt.steps(), 1);
    }

    #[test]
    fn hyperparameters_out_of_range_are_errors() {
        let mut params = vec![arr(&[1.0])];
        let g = [arr(&[1.0])];
        assert!(GradientDescent::new(-0.1).step(&mut params, &g).is_err());
        assert!(GradientDescent::new(f64::NAN)
            .step(&mut params, &g)
            .is_err());
        let err = Adam::new(0.1)
            .with_betas(1.0, 0.999)
            .step(&mut params, &g)
            .unwrap_err();
        assert!(
            err.to_string().contains("beta1 = 1 is out of range"),
            "{err}"
        );
        assert!(Adam::new(0.1).with_eps(0.0).step(&mut params, &g).is_err());
        assert_eq!(params[0], arr(&[1.0]));
    }

    #[test]
    fn step_vars_without_a_gradient_is_an_error() {
        let tape = Tape::new();
        let x = tape.var(arr(&[1.0]));
        let y = tape.var(arr(&[2.0]));
        let loss = x.mul(x).unwrap().sum().unwrap();
        let grads = tape.backward(loss, &[x]).unwrap();
        let mut params = vec![arr(&[1.0]), arr(&[2.0])];
        let err = Adam::new(0.1)
            .step_vars(&mut params, &grads, &[x, y])
            .unwrap_err();
        assert!(
            err.to_string().contains("no gradient for parameter 1"),
            "{err}"
        );

        let other = Tape::new();
        let z = other.var(arr(&[1.0]));
        let err = GradientDescent::new(0.1)
            .step_vars(&mut params[..1], &grads, &[z])
            .unwrap_err();
        assert!(
            err.to_string().contains("no gradient for parameter 0"),
            "{err}"
        );
        assert_eq!(params, vec![arr(&[1.0]), arr(&[2.0])]);
    }

    fn arr(values: &[f64]) -> ArrayD<f64> {
        ArrayD::from_shape_vec(IxDyn(&[values.len()]), values.to_vec()).unwrap()
    }
}
