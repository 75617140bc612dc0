//! Gradient checking: central finite differences against [`Tape::backward`], and the
//! dot-product test `<A x, y> = <x, Aᵀ y>` for linear operators.

use ndarray::{ArrayD, ArrayViewD, IxDyn, Zip};

use crate::{Real, Result, Tape, TapeError, Var};

/// Tolerances of [`check_gradient`]: entry `k` passes if
/// `|g_backward − g_fd| ≤ abs_tol + rel_tol·|g_fd|`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GradCheckOptions {
    /// Relative tolerance.
    pub rel_tol: f64,
    /// Absolute tolerance.
    pub abs_tol: f64,
    /// Finite-difference step relative to `max(1, |x|)`; `None` picks
    /// [`Real::fd_step`] for the precision.
    pub step: Option<f64>,
}

impl GradCheckOptions {
    /// Tolerances that a correct gradient meets comfortably in precision `T`:
    /// `1e-6`/`1e-8` in f64, `3e-2`/`3e-3` in f32 (central differences in f32 lose
    /// about half the digits).
    pub fn for_type<T: Real>() -> Self {
        if T::EPS.as_f64() < 1e-10 {
            GradCheckOptions {
                rel_tol: 1e-6,
                abs_tol: 1e-8,
                step: None,
            }
        } else {
            GradCheckOptions {
                rel_tol: 3e-2,
                abs_tol: 3e-3,
                step: None,
            }
        }
    }
}

/// The outcome of [`check_gradient`].
#[derive(Debug, Clone, PartialEq)]
pub struct GradCheckReport {
    /// Largest `|g_backward − g_fd|` over all entries of all inputs.
    pub max_abs_err: f64,
    /// Largest `|g_backward − g_fd| / max(|g_fd|, tiny)`.
    pub max_rel_err: f64,
    /// `(input, flat index)` of the entry furthest outside the tolerance.
    pub worst: (usize, usize),
    /// Entries compared.
    pub entries: usize,
    /// Whether every entry met the tolerance.
    pub passed: bool,
}

/// A deterministic pseudo-random array with entries uniform in `[-1, 1)`
/// (splitmix64), for tests and checks that must not depend on a RNG crate.
pub fn test_array<T: Real>(shape: &[usize], seed: u64) -> ArrayD<T> {
    let mut state = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    ArrayD::from_shape_simple_fn(IxDyn(shape), || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        let unit = (z >> 11) as f64 / (1u64 << 53) as f64;
        T::from_f64(2.0 * unit - 1.0)
    })
}

/// Evaluates `f` on a fresh tape and reduces its output to the scalar
/// `Σ weight ⊙ f(inputs)` (the output itself if `weight` is `None`).
fn evaluate<T: Real, F>(f: &F, inputs: &[ArrayD<T>], weight: Option<&ArrayD<T>>) -> Result<f64>
where
    F: for<'t> Fn(&'t Tape<T>, &[Var<'t, T>]) -> Result<Var<'t, T>>,
{
    let tape = Tape::new();
    let vars: Vec<_> = inputs.iter().map(|x| tape.constant(x.clone())).collect();
    let out = f(&tape, &vars)?;
    let value = out.value();
    Ok(match weight {
        Some(w) => Zip::from(&*value)
            .and(w)
            .fold(0.0, |acc, &y, &w| acc + (y * w).as_f64()),
        None => value.iter().map(|y| y.as_f64()).sum(),
    })
}

/// Compares the gradient that [`Tape::backward`] gives for `f` at `inputs` with
/// central finite differences, entry by entry.
///
/// `f` records any computation on the tape it is given, from variables holding
/// `inputs`. A non-scalar output is contracted with a fixed pseudo-random weight
/// (a vector–Jacobian product with a generic seed), so every output entry counts.
///
/// # Errors
/// Whatever `f` or the backward sweep returns.
pub fn check_gradient<T: Real, F>(
    f: F,
    inputs: &[ArrayD<T>],
    options: GradCheckOptions,
) -> Result<GradCheckReport>
where
    F: for<'t> Fn(&'t Tape<T>, &[Var<'t, T>]) -> Result<Var<'t, T>>,
{
    let tape = Tape::new();
    let vars: Vec<_> = inputs.iter().map(|x| tape.var(x.clone())).collect();
    let out = f(&tape, &vars)?;
    let out_shape = out.shape();
    let weight =
        (out_shape.iter().product::<usize>() != 1).then(|| test_array::<T>(&out_shape, 0x5EED));
    let grads = match &weight {
        Some(w) => tape.backward_with_seed(out, w.clone(), &vars)?,
        None => tape.backward(out, &vars)?,
    };

    let step = options.step.unwrap_or_else(|| T::fd_step().as_f64());
    let mut report = GradCheckReport {
        max_abs_err: 0.0,
        max_rel_err: 0.0,
        worst: (0, 0),
        entries: 0,
        passed: true,
    };
    let mut worst_excess = f64::NEG_INFINITY;
    let mut perturbed: Vec<ArrayD<T>> = inputs.to_vec();
    for (k, var) in vars.iter().enumerate() {
        let analytic = grads
            .get(*var)
            .ok_or_else(|| TapeError::invalid("check_gradient", "missing gradient"))?;
        for idx in 0..inputs[k].len() {
            let x = inputs[k].as_slice_memory_order().map(|s| s[idx]);
            let x = x.unwrap_or_else(|| *inputs[k].iter().nth(idx).expect("index in range"));
            // Perturb in the input's own precision so that h is exactly representable.
            let h = T::from_f64(step * x.as_f64().abs().max(1.0));
            let h_exact = ((x + h) - (x - h)).as_f64();
            let mut eval_at = |value: T| -> Result<f64> {
                set_flat(&mut perturbed[k], idx, value);
                let v = evaluate(&f, &perturbed, weight.as_ref());
                set_flat(&mut perturbed[k], idx, x);
                v
            };
            let fd = (eval_at(x + h)? - eval_at(x - h)?) / h_exact;
            let ad = get_flat(analytic, idx).as_f64();
            let abs_err = (ad - fd).abs();
            let rel_err = abs_err / fd.abs().max(f64::MIN_POSITIVE);
            report.max_abs_err = report.max_abs_err.max(abs_err);
            report.max_rel_err = report.max_rel_err.max(rel_err);
            let excess = abs_err - (options.abs_tol + options.rel_tol * fd.abs());
            if excess > worst_excess || ad.is_nan() || fd.is_nan() {
                worst_excess = if excess.is_nan() {
                    f64::INFINITY
                } else {
                    excess
                };
                report.worst = (k, idx);
            }
            if excess > 0.0 || excess.is_nan() {
                report.passed = false;
            }
            report.entries += 1;
        }
    }
    Ok(report)
}

fn get_flat<T: Real>(a: &ArrayD<T>, idx: usize) -> T {
    match a.as_slice() {
        Some(s) => s[idx],
        None => *a.iter().nth(idx).expect("index in range"),
    }
}

fn set_flat<T: Real>(a: &mut ArrayD<T>, idx: usize, value: T) {
    match a.as_slice_mut() {
        Some(s) => s[idx] = value,
        None => *a.iter_mut().nth(idx).expect("index in range") = value,
    }
}

/// The outcome of [`check_adjoint`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdjointReport {
    /// `<A x, y>`.
    pub forward_dot: f64,
    /// `<x, Aᵀ y>`.
    pub adjoint_dot: f64,
    /// `|forward_dot − adjoint_dot| / max(|A x|·|y|, |x|·|Aᵀ y|)`: about machine
    /// epsilon times the number of terms for a correct pair.
    pub rel_err: f64,
}

impl AdjointReport {
    /// Whether the relative error is within `tol`.
    pub fn passes(&self, tol: f64) -> bool {
        self.rel_err <= tol
    }
}

/// The dot-product test of a linear operator against its transpose:
/// `<A x, y> = <x, Aᵀ y>`, evaluated in `f64` sums.
///
/// # Errors
/// [`TapeError::ShapeMismatch`] if `A x` does not have `y`'s shape or `Aᵀ y` does not
/// have `x`'s.
pub fn check_adjoint<T: Real>(
    apply: impl Fn(ArrayViewD<'_, T>) -> ArrayD<T>,
    apply_transpose: impl Fn(ArrayViewD<'_, T>) -> ArrayD<T>,
    x: ArrayViewD<'_, T>,
    y: ArrayViewD<'_, T>,
) -> Result<AdjointReport> {
    let ax = apply(x.view());
    let aty = apply_transpose(y.view());
    if ax.shape() != y.shape() {
        return Err(TapeError::shape(
            "check_adjoint: A x vs y",
            ax.shape(),
            y.shape(),
        ));
    }
    if aty.shape() != x.shape() {
        return Err(TapeError::shape(
            "check_adjoint: Aᵀ y vs x",
            aty.shape(),
            x.shape(),
        ));
    }
    let dot = |a: &ArrayViewD<'_, T>, b: &ArrayViewD<'_, T>| {
        Zip::from(a)
            .and(b)
            .fold(0.0, |acc, &p, &q| acc + p.as_f64() * q.as_f64())
    };
    let norm = |a: &ArrayViewD<'_, T>| dot(a, a).sqrt();
    let forward_dot = dot(&ax.view(), &y);
    let adjoint_dot = dot(&x, &aty.view());
    let scale = (norm(&ax.view()) * norm(&y)).max(norm(&x) * norm(&aty.view()));
    let rel_err = if scale == 0.0 {
        (forward_dot - adjoint_dot).abs()
    } else {
        (forward_dot - adjoint_dot).abs() / scale
    };
    Ok(AdjointReport {
        forward_dot,
        adjoint_dot,
        rel_err,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_of_product_passes_and_a_wrong_one_fails() {
        let x = test_array::<f64>(&[5], 1);
        let ok = check_gradient(
            |_, v| v[0].mul(v[0])?.sum(),
            std::slice::from_ref(&x),
            GradCheckOptions::for_type::<f64>(),
        )
        .unwrap();
        assert!(ok.passed, "{ok:?}");
        assert_eq!(ok.entries, 5);

        // A plugin with a deliberately wrong adjoint must fail the check.
        struct Wrong;
        impl crate::Op<f64> for Wrong {
            fn name(&self) -> &str {
                "wrong"
            }
            fn forward(&mut self, i: &[ArrayViewD<'_, f64>]) -> Result<Vec<ArrayD<f64>>> {
                Ok(vec![i[0].mapv(|x| x * x)])
            }
            fn backward(
                &self,
                a: &crate::BackwardArgs<'_, f64>,
            ) -> Result<Vec<Option<ArrayD<f64>>>> {
                Ok(vec![Some(a.grad_out().to_owned())]) // should be 2x·g
            }
        }
        let bad = check_gradient(
            |t, v| t.apply(Wrong, &[v[0]])?.sum(),
            &[x],
            GradCheckOptions::for_type::<f64>(),
        )
        .unwrap();
        assert!(!bad.passed);
    }

    #[test]
    fn adjoint_test_detects_a_wrong_transpose() {
        let m = test_array::<f64>(&[3, 4], 2)
            .into_dimensionality::<ndarray::Ix2>()
            .unwrap();
        let x = test_array::<f64>(&[4], 3);
        let y = test_array::<f64>(&[3], 4);
        let a = |v: ArrayViewD<'_, f64>| {
            m.dot(&v.into_dimensionality::<ndarray::Ix1>().unwrap())
                .into_dyn()
        };
        let at = |v: ArrayViewD<'_, f64>| {
            m.t()
                .dot(&v.into_dimensionality::<ndarray::Ix1>().unwrap())
                .into_dyn()
        };
        let good = check_adjoint(a, at, x.view(), y.view()).unwrap();
        assert!(good.passes(1e-14), "{good:?}");
        let wrong_t = |v: ArrayViewD<'_, f64>| {
            let mut r = m.t().dot(&v.into_dimensionality::<ndarray::Ix1>().unwrap());
            r[0] += 0.1;
            r.into_dyn()
        };
        let bad = check_adjoint(a, wrong_t, x.view(), y.view()).unwrap();
        assert!(!bad.passes(1e-6));
    }

    #[test]
    fn test_arrays_are_deterministic_and_in_range() {
        let a = test_array::<f64>(&[100], 7);
        assert_eq!(a, test_array::<f64>(&[100], 7));
        assert_ne!(a, test_array::<f64>(&[100], 8));
        assert!(a.iter().all(|v| (-1.0..1.0).contains(v)));
    }
}
