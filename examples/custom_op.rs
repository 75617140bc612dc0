//! A first gradient on the tape, then a plugin op with a hand-written adjoint: one
//! explicit step of periodic 1-D diffusion, checked against the same step written in
//! primitives, against finite differences and by the dot-product test.
//!
//! Tutorial: docs/01-tape-and-custom-ops.md. Run:
//! `cargo run --release --example custom_op` (`-- --small` for the CI size).

mod common;

use diffphys::prelude::*;
use ndarray::{s, Array1, ArrayView1, IxDyn, Zip};

// ---------------------------------------------------------------------------
// Part 1: a first gradient.

/// `f(x) = Σ x² sin x` on the tape; returns the largest difference between the
/// tape's gradient and the analytic `∂f/∂xᵢ = 2 xᵢ sin xᵢ + xᵢ² cos xᵢ`.
fn first_gradient(n: usize) -> Result<f64, TapeError> {
    let tape = Tape::<f64>::new();
    let x = tape.var(Array1::linspace(-2.0, 2.0, n).into_dyn());
    let f = x.mul(x)?.mul(x.sin()?)?.sum()?;
    let grads = tape.backward(f, &[x])?;

    let analytic = x.value().mapv(|x| 2.0 * x * x.sin() + x * x * x.cos());
    let tape_grad = grads.get(x).expect("x was requested");
    Ok(max_abs_diff(tape_grad, &analytic))
}

// ---------------------------------------------------------------------------
// Part 2: the operator as two plain functions, forward and adjoint.

/// The periodic Laplacian stencil `(L u)ᵢ = uᵢ₋₁ − 2uᵢ + uᵢ₊₁` (unit spacing): the
/// interior as a sum of shifted slices, the two wrapped ends once.
fn periodic_laplacian<T: Real>(u: ArrayView1<'_, T>) -> Array1<T> {
    let n = u.len();
    let two = T::from_f64(2.0);
    let mut lap = Array1::zeros(n);
    Zip::from(lap.slice_mut(s![1..n - 1]))
        .and(u.slice(s![..n - 2]))
        .and(u.slice(s![1..n - 1]))
        .and(u.slice(s![2..]))
        .for_each(|l, &west, &here, &east| *l = west - two * here + east);
    lap[0] = u[n - 1] - two * u[0] + u[1];
    lap[n - 1] = u[n - 2] - two * u[n - 1] + u[0];
    lap
}

/// One explicit diffusion step `y = u + κ L u`, with `κ = ν Δt / Δx²` (stable for
/// `0 ≤ κ ≤ ½`).
fn diffusion_step<T: Real>(u: ArrayView1<'_, T>, kappa: T) -> Array1<T> {
    let mut y = periodic_laplacian(u);
    y.zip_mut_with(&u, |y, &u| *y = u + kappa * *y);
    y
}

/// Adjoint in `u`: `grad_u = (I + κ L)ᵀ grad_y = grad_y + κ L grad_y`, because the
/// periodic Laplacian is symmetric. (It is [`diffusion_step`] applied to `grad_y`.)
fn diffusion_step_grad_u<T: Real>(kappa: T, grad_y: ArrayView1<'_, T>) -> Array1<T> {
    diffusion_step(grad_y, kappa)
}

/// Adjoint in `κ`: `grad_κ = Σᵢ grad_yᵢ (L u)ᵢ`.
fn diffusion_step_grad_kappa<T: Real>(u: ArrayView1<'_, T>, grad_y: ArrayView1<'_, T>) -> T {
    periodic_laplacian(u).dot(&grad_y)
}

// ---------------------------------------------------------------------------
// Part 3: the tape plugin, a thin adapter over the plain functions.

/// `y = u + κ L u` on the tape. Inputs: `u` (1-D, at least 3 cells) and `κ` (one
/// element). Keeps nothing beyond its inputs, which the tape holds anyway.
struct DiffusionStep;

/// `u` as a 1-D view with at least 3 cells, and `κ` as a scalar.
fn step_inputs<'a, T: Real>(
    inputs: &'a [ArrayViewD<'a, T>],
) -> Result<(ArrayView1<'a, T>, T), TapeError> {
    let u = inputs[0].view().into_dimensionality().map_err(|_| {
        TapeError::invalid(
            "diffusion_step",
            format!("u must be 1-D, got shape {:?}", inputs[0].shape()),
        )
    })?;
    if u.len() < 3 {
        return Err(TapeError::invalid(
            "diffusion_step",
            "u needs at least 3 cells",
        ));
    }
    let kappa = match inputs[1].len() {
        1 => *inputs[1].iter().next().expect("one element"),
        _ => {
            return Err(TapeError::shape(
                "diffusion_step (κ must be a scalar)",
                inputs[1].shape(),
                &[],
            ))
        }
    };
    Ok((u, kappa))
}

impl<T: Real> Op<T> for DiffusionStep {
    fn name(&self) -> &str {
        "diffusion_step"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>, TapeError> {
        let (u, kappa) = step_inputs(inputs)?;
        Ok(vec![diffusion_step(u, kappa).into_dyn()])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>, TapeError> {
        let (u, kappa) = step_inputs(args.inputs)?;
        let grad_y = args
            .grad_out()
            .view()
            .into_dimensionality()
            .expect("y has u's shape");
        // Greedy: compute only the gradients someone asked for.
        let grad_u = args
            .needs(0)
            .then(|| diffusion_step_grad_u(kappa, grad_y).into_dyn());
        let grad_kappa = args.needs(1).then(|| {
            ArrayD::from_elem(
                args.input(1).raw_dim(),
                diffusion_step_grad_kappa(u, grad_y),
            )
        });
        Ok(vec![grad_u, grad_kappa])
    }
}

// ---------------------------------------------------------------------------
// Part 4: the same step in primitives, the reference.

/// `y = u + κ (roll(u, 1) + roll(u, −1) − 2u)`: seven recorded ops where the plugin
/// records one.
fn diffusion_step_primitives<'t>(
    u: Var<'t, f64>,
    kappa: Var<'t, f64>,
) -> Result<Var<'t, f64>, TapeError> {
    let lap = u.roll(1, 0)?.add(u.roll(-1, 0)?)?.sub(u.mul_scalar(2.0)?)?;
    u.add(lap.mul(kappa)?)
}

/// `loss = Σ (u_steps − target)²` after `steps` diffusion steps taken by `step`.
fn loss_after<'t>(
    steps: usize,
    u0: Var<'t, f64>,
    kappa: Var<'t, f64>,
    target: Var<'t, f64>,
    step: impl Fn(Var<'t, f64>, Var<'t, f64>) -> Result<Var<'t, f64>, TapeError>,
) -> Result<Var<'t, f64>, TapeError> {
    let mut u = u0;
    for _ in 0..steps {
        u = step(u, kappa)?;
    }
    let misfit = u.sub(target)?;
    misfit.mul(misfit)?.sum()
}

/// The plugin as a step function for [`loss_after`].
fn plugin_step<'t>(u: Var<'t, f64>, kappa: Var<'t, f64>) -> Result<Var<'t, f64>, TapeError> {
    u.tape().apply(DiffusionStep, &[u, kappa])
}

/// A step of the diffusion, as the plugin or as primitives.
type StepFn = for<'t> fn(Var<'t, f64>, Var<'t, f64>) -> Result<Var<'t, f64>, TapeError>;

/// What one run of [`loss_after`] and its backward sweep gives.
struct Run {
    loss: f64,
    grad_u0: ArrayD<f64>,
    grad_kappa: f64,
    stats: TapeStats,
}

/// Records `steps` steps of `step` from `u0` on a fresh tape and sweeps back to
/// `u0` and `κ`.
fn gradients(
    step: StepFn,
    steps: usize,
    u0: &ArrayD<f64>,
    kappa: f64,
    target: &ArrayD<f64>,
) -> Result<Run, TapeError> {
    let tape = Tape::new();
    let u = tape.var(u0.clone());
    let k = tape.var(ArrayD::from_elem(IxDyn(&[]), kappa));
    let loss = loss_after(steps, u, k, tape.constant(target.clone()), step)?;
    let mut grads = tape.backward(loss, &[u, k])?;
    Ok(Run {
        loss: loss.item()?,
        grad_u0: grads.take(u).expect("u was requested"),
        grad_kappa: grads.take(k).expect("κ was requested")[[]],
        stats: tape.stats(),
    })
}

fn max_abs_diff(a: &ArrayD<f64>, b: &ArrayD<f64>) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// A first gradient on the tape, then a plugin op with a hand-written adjoint, checked three ways.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Cli { common: args } = common::parse_args("custom_op")?;
    let n = args.pick(256, 32);
    let steps = args.pick(50, 10);

    // Part 1.
    let err = first_gradient(n)?;
    println!("first gradient: f(x) = Σ x² sin x on {n} points, max |tape − analytic| = {err:.2e}");

    // Part 5: the plugin against the primitive chain, same loss, same inputs.
    let u0 = test_array::<f64>(&[n], 1);
    let target = test_array::<f64>(&[n], 2).mapv(|t| 0.1 * t);
    let kappa = 0.2;
    let plugin = gradients(plugin_step, steps, &u0, kappa, &target)?;
    let reference = gradients(diffusion_step_primitives, steps, &u0, kappa, &target)?;
    println!(
        "{steps} diffusion steps on {n} cells: loss {:.6} (plugin) vs {:.6} (primitives); \
         ∂loss/∂κ {:.6} vs {:.6}",
        plugin.loss, reference.loss, plugin.grad_kappa, reference.grad_kappa
    );
    println!(
        "tape: plugin {} nodes, {} bytes peak; primitives {} nodes, {} bytes peak",
        plugin.stats.nodes,
        plugin.stats.peak_bytes,
        reference.stats.nodes,
        reference.stats.peak_bytes
    );
    let max_diff = max_abs_diff(&plugin.grad_u0, &reference.grad_u0)
        .max((plugin.grad_kappa - reference.grad_kappa).abs());
    println!("max |plugin gradient − primitive gradient| over u₀ and κ = {max_diff:.2e}");

    // Part 6: the plugin's gradient against finite differences, in both inputs...
    let report = check_gradient(
        |tape, v| loss_after(3, v[0], v[1], tape.constant(target.clone()), plugin_step),
        &[u0.clone(), ArrayD::from_elem(IxDyn(&[]), kappa)],
        GradCheckOptions::for_type::<f64>(),
    )?;
    println!(
        "check_gradient (3 plugin steps): passed = {}, max abs err {:.2e} over {} entries",
        report.passed, report.max_abs_err, report.entries
    );
    // ...and its adjoint in u by the dot-product test <A x, y> = <x, Aᵀ y>, which
    // fails for a stencil that is not symmetric (one-sided differences, upwinding).
    let adjoint = check_adjoint(
        |x: ArrayViewD<'_, f64>| {
            diffusion_step(x.into_dimensionality().expect("1-D"), kappa).into_dyn()
        },
        |y: ArrayViewD<'_, f64>| {
            diffusion_step_grad_u(kappa, y.into_dimensionality().expect("1-D")).into_dyn()
        },
        test_array::<f64>(&[n], 3).view(),
        test_array::<f64>(&[n], 4).view(),
    )?;
    println!("dot-product test: relative error {:.2e}", adjoint.rel_err);
    if !report.passed || !adjoint.passes(1e-12) || max_diff > 1e-10 {
        return Err("the plugin disagrees with its references".into());
    }
    args.write_npy(&[
        ("u0", u0.view(), "the initial field [n]"),
        ("target", target.view(), "the target of the loss [n]"),
        (
            "grad_u0_plugin",
            plugin.grad_u0.view(),
            "∂loss/∂u₀ through the plugin op [n]",
        ),
        (
            "grad_u0_primitives",
            reference.grad_u0.view(),
            "∂loss/∂u₀ through the primitive chain [n]",
        ),
    ])?;

    common::print_json_line(&serde_json::json!({
        "example": "custom_op",
        "max_abs_diff": max_diff,
    }));
    Ok(())
}
