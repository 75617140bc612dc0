//! The Fourier pressure solve of a periodic box against the sparse Cholesky
//! factorisation of the same operator: the projection, the pressure and the
//! adjoint agree to rounding, on a box whose sides and cells differ in
//! length; a scene the transform cannot solve is refused when built.

mod common;

use common::velocity;
use diffphys_flow::diagnostics::max_divergence;
use diffphys_flow::pressure::{project, project_vjp};
use diffphys_flow::{FlowError, Obstacle, PressureSolver, Scene, Sides};
use diffphys_tape::test_array;
use ndarray::Array2;

fn periodic_box(solver: PressureSolver) -> Scene {
    Scene::builder(24, 10, [2.0, 1.3])
        .sides(Sides::periodic())
        .viscosity(0.01)
        .dt(0.01)
        .pressure_solver(solver)
        .build()
        .unwrap()
}

fn max_diff(a: &Array2<f64>, b: &Array2<f64>) -> f64 {
    (a - b).iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

#[test]
fn fourier_projection_matches_the_cholesky_projection() {
    let fft = periodic_box(PressureSolver::Fourier);
    let chol = periodic_box(PressureSolver::Cholesky);
    let (ux, uy) = velocity(&fft, 1.0, 5);
    let tau = 0.5 * fft.dt();
    let a = project(fft.pressure_system(), tau, ux.view(), uy.view(), None).unwrap();
    let b = project(chol.pressure_system(), tau, ux.view(), uy.view(), None).unwrap();
    let scale = b.pressure.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        scale > 1.0,
        "the test field should need a pressure: {scale}"
    );
    assert!(max_diff(&a.ux, &b.ux) < 1e-12, "{}", max_diff(&a.ux, &b.ux));
    assert!(max_diff(&a.uy, &b.uy) < 1e-12, "{}", max_diff(&a.uy, &b.uy));
    let dp = max_diff(&a.pressure, &b.pressure) / scale;
    assert!(dp < 1e-12, "pressure differs by {dp:e} (relative)");
    assert_eq!(a.iterations, 0, "a direct solve");
    let div = max_divergence(fft.grid(), fft.solid(), a.ux.view(), a.uy.view()).unwrap();
    assert!(div < 1e-11, "max |div u'| = {div:e}");
}

#[test]
fn fourier_adjoint_matches_the_cholesky_adjoint_with_a_pressure_gradient_of_nonzero_mean() {
    let fft = periodic_box(PressureSolver::Fourier);
    let chol = periodic_box(PressureSolver::Cholesky);
    let (gx, gy) = velocity(&fft, 1.0, 9);
    // a pressure gradient whose mean is not zero: the solve must take the
    // pseudo-inverse, as the Cholesky path does
    let gp: Array2<f64> = test_array::<f64>(&fft.grid().cell_shape(), 11)
        .mapv(|v| v + 0.7)
        .into_dimensionality()
        .unwrap();
    let tau = fft.dt();
    let a = project_vjp(
        fft.pressure_system(),
        tau,
        gx.view(),
        gy.view(),
        Some(gp.view()),
    )
    .unwrap();
    let b = project_vjp(
        chol.pressure_system(),
        tau,
        gx.view(),
        gy.view(),
        Some(gp.view()),
    )
    .unwrap();
    let scale = b.0.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        max_diff(&a.0, &b.0) < 1e-11 * scale,
        "{}",
        max_diff(&a.0, &b.0)
    );
    assert!(
        max_diff(&a.1, &b.1) < 1e-11 * scale,
        "{}",
        max_diff(&a.1, &b.1)
    );
}

#[test]
fn fourier_refuses_walls_and_obstacles() {
    let walls = Scene::builder(8, 8, [1.0, 1.0])
        .sides(Sides::cavity(1.0))
        .pressure_solver(PressureSolver::Fourier)
        .build();
    let obstacle = Scene::builder(16, 16, [1.0, 1.0])
        .sides(Sides::periodic())
        .obstacle(Obstacle::cylinder([0.5, 0.5], 0.2))
        .pressure_solver(PressureSolver::Fourier)
        .build();
    for (what, r) in [("walls", walls), ("obstacle", obstacle)] {
        match r {
            Err(e @ FlowError::InvalidScene { .. }) => {
                assert!(e.to_string().contains("Fourier"), "{what}: {e}");
            }
            other => panic!("{what}: expected InvalidScene, got {other:?}"),
        }
    }
}

#[test]
fn implicit_viscosity_on_the_periodic_box_solves_its_helmholtz_system() {
    use diffphys_flow::diffusion::diffuse;
    use diffphys_flow::ViscosityMode;
    // the implicit step x = (I − ν dt L)⁻¹ u is solved by FFT here; one
    // explicit step backwards in time, x − ν dt L x, must give u back
    let scene = periodic_box(PressureSolver::Fourier);
    let (ux, uy) = velocity(&scene, 1.0, 21);
    let walls = scene.params::<f64>().wall_speed;
    let (nu, dt) = (0.3, 0.05); // ν dt / h² ≈ 5: far beyond explicit stability
    let (x, y) = diffuse(
        scene.diffusion(),
        ViscosityMode::Implicit,
        dt,
        ux.view(),
        uy.view(),
        nu,
        walls.view(),
    )
    .unwrap();
    let change = max_diff(&x, &ux);
    assert!(change > 1e-2, "the step must smooth the field: {change}");
    let (bx, by) = diffuse(
        scene.diffusion(),
        ViscosityMode::Explicit,
        -dt,
        x.view(),
        y.view(),
        nu,
        walls.view(),
    )
    .unwrap();
    assert!(max_diff(&bx, &ux) < 1e-12, "{}", max_diff(&bx, &ux));
    assert!(max_diff(&by, &uy) < 1e-12, "{}", max_diff(&by, &uy));
}

#[test]
fn fourier_solves_refuse_non_finite_input() {
    use diffphys_flow::diffusion::diffuse;
    use diffphys_flow::ViscosityMode;
    let scene = periodic_box(PressureSolver::Fourier);
    let (mut ux, uy) = velocity(&scene, 1.0, 31);
    ux[[3, 2]] = f64::NAN;
    match project(
        scene.pressure_system(),
        scene.dt(),
        ux.view(),
        uy.view(),
        None,
    ) {
        Err(FlowError::NonFinite { step, .. }) => assert_eq!(step, "pressure solve"),
        other => panic!("expected NonFinite, got {other:?}"),
    }
    let walls = scene.params::<f64>().wall_speed;
    let r = diffuse(
        scene.diffusion(),
        ViscosityMode::Implicit,
        0.01,
        ux.view(),
        uy.view(),
        0.1,
        walls.view(),
    );
    match r {
        Err(FlowError::NonFinite { step, .. }) => assert_eq!(step, "viscosity solve"),
        other => panic!("expected NonFinite, got {other:?}"),
    }
}
