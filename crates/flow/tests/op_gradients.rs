//! Every op of the step: its gradient against central finite differences in
//! f64, and the dot-product test where it is linear.

mod common;

use common::{combine, pack, scalar, scenes, unpack, velocity};
use diffphys_flow::advection::{
    advect_velocity, advect_velocity_vjp, AdvectScalar, AdvectVelocity,
};
use diffphys_flow::boundaries::EnforceBoundaries;
use diffphys_flow::diagnostics::{
    divergence, divergence_vjp, obstacle_force, vorticity, vorticity_vjp, Divergence,
    ObstacleForce, Vorticity,
};
use diffphys_flow::diffusion::{diffuse, diffuse_vjp, Diffuse};
use diffphys_flow::forcing::{buoyancy, buoyancy_vjp, Buoyant};
use diffphys_flow::pressure::{
    project, project_vjp, subtract_pressure_gradient, subtract_pressure_gradient_vjp, Project,
    SolveCounter, SubtractPressureGradient,
};
use diffphys_flow::{Advection, Scene, ViscosityMode};
use diffphys_tape::{
    check_adjoint, check_gradient, test_array, ArrayD, ArrayViewD, GradCheckOptions, Op, Tape, Var,
};
use ndarray::{Array1, Array2};

fn record<'t, O: Op<f64> + 'static>(
    tape: &'t Tape<f64>,
    op: O,
    inputs: &[Var<'t, f64>],
) -> Vec<Var<'t, f64>> {
    tape.apply_multi(op, inputs).unwrap()
}

fn assert_gradient<F>(what: &str, f: F, inputs: &[ArrayD<f64>])
where
    F: for<'t> Fn(&'t Tape<f64>, &[Var<'t, f64>]) -> diffphys_tape::Result<Var<'t, f64>>,
{
    let report = check_gradient(f, inputs, GradCheckOptions::for_type::<f64>()).unwrap();
    assert!(report.passed, "{what}: {report:?}");
    assert!(report.entries > 0);
}

fn walls(scene: &Scene) -> ArrayD<f64> {
    // the scene's wall speeds plus a nonzero value on every side
    let p = scene.params::<f64>();
    (p.wall_speed + Array1::from(vec![0.3, -0.2, 0.4, 0.7])).into_dyn()
}

fn u_inputs(scene: &Scene, amp: f64, seed: u64) -> (ArrayD<f64>, ArrayD<f64>) {
    let (ux, uy) = velocity(scene, amp, seed);
    (ux.into_dyn(), uy.into_dyn())
}

#[test]
fn enforce_boundaries_gradient() {
    let scene = common::channel().build().unwrap();
    let (ux, uy) = u_inputs(&scene, 1.0, 1);
    let inflow = test_array::<f64>(&[scene.inflow_len()], 3);
    let op = EnforceBoundaries {
        grid: scene.grid().clone(),
        faces: scene.faces().clone(),
    };
    assert_gradient(
        "enforce_boundaries",
        move |t, v| combine(t, &record(t, op.clone(), v)),
        &[ux, uy, inflow],
    );
}

#[test]
fn velocity_advection_gradients() {
    for scheme in [
        Advection::SemiLagrangian,
        Advection::MacCormack { limiter: false },
        Advection::MacCormack { limiter: true },
    ] {
        for (name, b) in scenes() {
            let scene = b.build().unwrap();
            let (ux, uy) = u_inputs(&scene, 1.0, 5);
            let op = AdvectVelocity {
                grid: scene.grid().clone(),
                faces: scene.faces().clone(),
                scheme,
                dt: 0.7 * scene.dt(),
            };
            let self_op = op.clone();
            assert_gradient(
                &format!("velocity self-advection {scheme:?} {name}"),
                move |t, v| {
                    combine(
                        t,
                        &record(t, self_op.clone(), &[v[0], v[1], v[0], v[1], v[2]]),
                    )
                },
                &[ux.clone(), uy.clone(), walls(&scene)],
            );
            let (qx, qy) = u_inputs(&scene, 1.0, 6);
            assert_gradient(
                &format!("velocity advection {scheme:?} {name}"),
                move |t, v| combine(t, &record(t, op.clone(), v)),
                &[qx, qy, ux, uy, walls(&scene)],
            );
        }
    }
}

#[test]
fn velocity_advection_is_linear_in_the_field_for_frozen_tracing() {
    // advect_velocity is nonlinear; its vjp restricted to zero wall speeds and
    // zero velocity (pure transport by u = 0) is the identity: a cheap sanity
    // check that the vjp of a zero flow is the identity on every face.
    let scene = common::mixed().build().unwrap();
    let g = scene.grid();
    let zx = Array2::<f64>::zeros((g.shape_x()[0], g.shape_x()[1]));
    let zy = Array2::<f64>::zeros((g.shape_y()[0], g.shape_y()[1]));
    let w = Array1::<f64>::zeros(4);
    let (gx, gy) = velocity(&scene, 1.0, 9);
    let r = advect_velocity_vjp(
        scene.grid(),
        scene.faces(),
        Advection::SemiLagrangian,
        0.05,
        (zx.view(), zy.view()),
        (zx.view(), zy.view()),
        w.view(),
        (gx.view(), gy.view()),
    )
    .unwrap();
    assert_eq!(r.field_x, gx);
    assert_eq!(r.field_y, gy);
    let (a, b) = advect_velocity(
        scene.grid(),
        scene.faces(),
        Advection::SemiLagrangian,
        0.05,
        (zx.view(), zy.view()),
        (zx.view(), zy.view()),
        w.view(),
    )
    .unwrap();
    assert!(a.iter().chain(b.iter()).all(|v| *v == 0.0));
}

/// With the tracing velocity held fixed, the advection is linear in the
/// advected field for semi-Lagrangian and unlimited MacCormack steps (both
/// compositions of interpolations): its product with respect to the field
/// is its transpose, `⟨A q, y⟩ = ⟨q, Aᵀ y⟩`, on every scene (the periodic
/// box takes the segment kernels of both directions).
#[test]
fn velocity_advection_in_the_field_passes_the_dot_product_test() {
    for scheme in [
        Advection::SemiLagrangian,
        Advection::MacCormack { limiter: false },
    ] {
        for (name, b) in scenes() {
            let scene = b.build().unwrap();
            let g = scene.grid();
            let shapes = [g.shape_x(), g.shape_y()];
            let (ux, uy) = velocity(&scene, 1.0, 31);
            // zero wall speeds: the ghosts are then linear in the field too
            let w = Array1::<f64>::zeros(4);
            let dt = 0.7 * scene.dt();
            let apply = |x: ArrayViewD<'_, f64>| {
                let q = unpack(&x.to_owned(), &shapes);
                let (a, b) = advect_velocity(
                    g,
                    scene.faces(),
                    scheme,
                    dt,
                    (q[0].view(), q[1].view()),
                    (ux.view(), uy.view()),
                    w.view(),
                )
                .unwrap();
                pack(&[&a, &b])
            };
            let apply_t = |y: ArrayViewD<'_, f64>| {
                let gy = unpack(&y.to_owned(), &shapes);
                let zx = Array2::<f64>::zeros((shapes[0][0], shapes[0][1]));
                let zy = Array2::<f64>::zeros((shapes[1][0], shapes[1][1]));
                // the field's product does not read the field (linear)
                let r = advect_velocity_vjp(
                    g,
                    scene.faces(),
                    scheme,
                    dt,
                    (zx.view(), zy.view()),
                    (ux.view(), uy.view()),
                    w.view(),
                    (gy[0].view(), gy[1].view()),
                )
                .unwrap();
                pack(&[&r.field_x, &r.field_y])
            };
            let (x0, x1) = velocity(&scene, 1.0, 33);
            let (y0, y1) = velocity(&scene, 1.0, 35);
            let rep = check_adjoint(
                apply,
                apply_t,
                pack(&[&x0, &x1]).view(),
                pack(&[&y0, &y1]).view(),
            )
            .unwrap();
            assert!(
                rep.passes(1e-12),
                "advection {scheme:?} {name} dot test: {rep:?}"
            );
        }
    }
}

#[test]
fn scalar_advection_gradients() {
    for scheme in [
        Advection::SemiLagrangian,
        Advection::MacCormack { limiter: false },
        Advection::MacCormack { limiter: true },
    ] {
        for (name, b) in scenes() {
            let scene = b.build().unwrap();
            let (ux, uy) = u_inputs(&scene, 1.0, 7);
            let s = test_array::<f64>(&scene.grid().cell_shape(), 8);
            let op = AdvectScalar {
                grid: scene.grid().clone(),
                faces: scene.faces().clone(),
                scheme,
                dt: 0.7 * scene.dt(),
            };
            assert_gradient(
                &format!("scalar advection {scheme:?} {name}"),
                move |t, v| combine(t, &record(t, op.clone(), v)),
                &[s, ux, uy, walls(&scene)],
            );
        }
    }
}

#[test]
fn diffusion_gradients_and_adjoints() {
    for mode in [ViscosityMode::Explicit, ViscosityMode::Implicit] {
        for (name, b) in scenes() {
            let scene = b.build().unwrap();
            let (ux, uy) = u_inputs(&scene, 1.0, 11);
            let op = Diffuse {
                diffusion: scene.diffusion().clone(),
                mode,
                dt: scene.dt(),
            };
            assert_gradient(
                &format!("diffusion {mode:?} {name}"),
                move |t, v| combine(t, &record(t, op.clone(), v)),
                &[ux.clone(), uy.clone(), scalar(0.05), walls(&scene)],
            );
            // linear in u for zero wall speeds
            let g = scene.grid();
            let shapes = [g.shape_x(), g.shape_y()];
            let w0 = Array1::<f64>::zeros(4);
            let apply = |x: ArrayViewD<'_, f64>| {
                let p = unpack(&x.to_owned(), &shapes);
                let (a, b) = diffuse(
                    scene.diffusion(),
                    mode,
                    scene.dt(),
                    p[0].view(),
                    p[1].view(),
                    0.05,
                    w0.view(),
                )
                .unwrap();
                pack(&[&a, &b])
            };
            let apply_t = |y: ArrayViewD<'_, f64>| {
                let gy = unpack(&y.to_owned(), &shapes);
                let zx = Array2::<f64>::zeros((shapes[0][0], shapes[0][1]));
                let zy = Array2::<f64>::zeros((shapes[1][0], shapes[1][1]));
                // the implicit adjoint reads the output: that of the same x is not needed for u (linear)
                let (ox, oy) = diffuse(
                    scene.diffusion(),
                    mode,
                    scene.dt(),
                    zx.view(),
                    zy.view(),
                    0.05,
                    w0.view(),
                )
                .unwrap();
                let r = diffuse_vjp(
                    scene.diffusion(),
                    mode,
                    scene.dt(),
                    zx.view(),
                    zy.view(),
                    0.05,
                    w0.view(),
                    (ox.view(), oy.view()),
                    (gy[0].view(), gy[1].view()),
                )
                .unwrap();
                pack(&[&r.ux, &r.uy])
            };
            let (x0, x1) = velocity(&scene, 1.0, 21);
            let (y0, y1) = velocity(&scene, 1.0, 23);
            let rep = check_adjoint(
                apply,
                apply_t,
                pack(&[&x0, &x1]).view(),
                pack(&[&y0, &y1]).view(),
            )
            .unwrap();
            // the implicit map is a CG solve to a relative residual of 1e-10:
            // linear and self-adjoint only to about that
            let tol = if mode == ViscosityMode::Implicit {
                1e-9
            } else {
                1e-12
            };
            assert!(
                rep.passes(tol),
                "diffusion {mode:?} {name} dot test: {rep:?}"
            );
        }
    }
}

#[test]
fn projection_gradients_and_adjoints() {
    for (name, b) in scenes() {
        let scene = b.build().unwrap();
        let (ux, uy) = u_inputs(&scene, 1.0, 31);
        let guess = test_array::<f64>(&scene.grid().cell_shape(), 32);
        let op = Project {
            system: scene.pressure_system().clone(),
            tau: 0.5 * scene.dt(),
            counter: SolveCounter::new(),
        };
        assert_gradient(
            &format!("projection {name}"),
            move |t, v| {
                let g = t.constant(guess.clone());
                combine(t, &record(t, op.clone(), &[v[0], v[1], g]))
            },
            &[ux, uy],
        );
        let g = scene.grid();
        let shapes = [g.shape_x(), g.shape_y()];
        let tau = scene.dt();
        let apply = |x: ArrayViewD<'_, f64>| {
            let p = unpack(&x.to_owned(), &shapes);
            let r = project(scene.pressure_system(), tau, p[0].view(), p[1].view(), None).unwrap();
            pack(&[&r.ux, &r.uy, &r.pressure])
        };
        let apply_t = |y: ArrayViewD<'_, f64>| {
            let p = unpack(&y.to_owned(), &[shapes[0], shapes[1], g.cell_shape()]);
            let (a, b) = project_vjp(
                scene.pressure_system(),
                tau,
                p[0].view(),
                p[1].view(),
                Some(p[2].view()),
            )
            .unwrap();
            pack(&[&a, &b])
        };
        let (x0, x1) = velocity(&scene, 1.0, 41);
        let (y0, y1) = velocity(&scene, 1.0, 43);
        let y2: Array2<f64> = test_array::<f64>(&g.cell_shape(), 45)
            .into_dimensionality()
            .unwrap();
        let rep = check_adjoint(
            apply,
            apply_t,
            pack(&[&x0, &x1]).view(),
            pack(&[&y0, &y1, &y2]).view(),
        )
        .unwrap();
        assert!(rep.passes(1e-10), "projection {name} dot test: {rep:?}");
    }
}

#[test]
fn pressure_gradient_gradients_and_adjoints() {
    for (name, b) in scenes() {
        let scene = b.build().unwrap();
        let (ux, uy) = u_inputs(&scene, 1.0, 51);
        let p = test_array::<f64>(&scene.grid().cell_shape(), 52);
        let op = SubtractPressureGradient {
            grid: scene.grid().clone(),
            faces: scene.faces().clone(),
            c: 0.3,
        };
        assert_gradient(
            &format!("pressure gradient {name}"),
            move |t, v| combine(t, &record(t, op.clone(), v)),
            &[ux, uy, p],
        );
        let g = scene.grid();
        let shapes = [g.shape_x(), g.shape_y(), g.cell_shape()];
        let apply = |x: ArrayViewD<'_, f64>| {
            let a = unpack(&x.to_owned(), &shapes);
            let (p, q) = subtract_pressure_gradient(
                scene.grid(),
                scene.faces(),
                0.3,
                a[0].view(),
                a[1].view(),
                a[2].view(),
            )
            .unwrap();
            pack(&[&p, &q])
        };
        let apply_t = |y: ArrayViewD<'_, f64>| {
            let a = unpack(&y.to_owned(), &shapes[..2]);
            let (p, q, r) = subtract_pressure_gradient_vjp(
                scene.grid(),
                scene.faces(),
                0.3,
                a[0].view(),
                a[1].view(),
            )
            .unwrap();
            pack(&[&p, &q, &r])
        };
        let x: ArrayD<f64> = test_array(&[shapes.iter().map(|s| s[0] * s[1]).sum()], 53);
        let y: ArrayD<f64> = test_array(&[shapes[..2].iter().map(|s| s[0] * s[1]).sum()], 54);
        let rep = check_adjoint(apply, apply_t, x.view(), y.view()).unwrap();
        assert!(rep.passes(1e-12), "pressure gradient {name}: {rep:?}");
    }
}

#[test]
fn buoyancy_gradients_and_adjoints() {
    let scene = common::mixed().build().unwrap();
    let g = scene.grid();
    let uy = test_array::<f64>(&g.shape_y(), 61);
    let s = test_array::<f64>(&g.cell_shape(), 62);
    let op = Buoyant {
        grid: scene.grid().clone(),
        faces: scene.faces().clone(),
        beta: 0.8,
        dt: 0.1,
    };
    assert_gradient(
        "buoyancy",
        move |t, v| combine(t, &record(t, op.clone(), v)),
        &[uy, s],
    );
    let shapes = [g.shape_y(), g.cell_shape()];
    let apply = |x: ArrayViewD<'_, f64>| {
        let a = unpack(&x.to_owned(), &shapes);
        pack(&[&buoyancy(
            scene.grid(),
            scene.faces(),
            0.8,
            0.1,
            a[0].view(),
            a[1].view(),
        )
        .unwrap()])
    };
    let apply_t = |y: ArrayViewD<'_, f64>| {
        let a = unpack(&y.to_owned(), &shapes[..1]);
        let (p, q) = buoyancy_vjp(scene.grid(), scene.faces(), 0.8, 0.1, a[0].view()).unwrap();
        pack(&[&p, &q])
    };
    let x: ArrayD<f64> = test_array(&[shapes.iter().map(|s| s[0] * s[1]).sum()], 63);
    let y: ArrayD<f64> = test_array(&[shapes[0][0] * shapes[0][1]], 64);
    let rep = check_adjoint(apply, apply_t, x.view(), y.view()).unwrap();
    assert!(rep.passes(1e-12), "buoyancy: {rep:?}");
}

#[test]
fn diagnostics_gradients_and_adjoints() {
    for (name, b) in scenes() {
        let scene = b.build().unwrap();
        let (ux, uy) = u_inputs(&scene, 1.0, 71);
        let p = test_array::<f64>(&scene.grid().cell_shape(), 72);
        let d = Divergence {
            grid: scene.grid().clone(),
        };
        assert_gradient(
            &format!("divergence {name}"),
            move |t, v| combine(t, &record(t, d.clone(), v)),
            &[ux.clone(), uy.clone()],
        );
        let w = Vorticity {
            grid: scene.grid().clone(),
        };
        assert_gradient(
            &format!("vorticity {name}"),
            move |t, v| combine(t, &record(t, w.clone(), v)),
            &[ux.clone(), uy.clone()],
        );
        let f = ObstacleForce {
            weights: scene.force_weights().clone(),
        };
        assert_gradient(
            &format!("force {name}"),
            move |t, v| combine(t, &record(t, f.clone(), v)),
            &[ux, uy, p, scalar(0.07)],
        );

        let g = scene.grid();
        let shapes = [g.shape_x(), g.shape_y()];
        let (x0, x1) = velocity(&scene, 1.0, 73);
        let x = pack(&[&x0, &x1]);
        let dy: ArrayD<f64> = test_array(&[g.nx * g.ny], 74);
        let rep = check_adjoint(
            |x| {
                let a = unpack(&x.to_owned(), &shapes);
                pack(&[&divergence(&scene, a[0].view(), a[1].view()).unwrap()])
            },
            |y| {
                let a = unpack(&y.to_owned(), &[g.cell_shape()]);
                let (p, q) = divergence_vjp(&scene, a[0].view()).unwrap();
                pack(&[&p, &q])
            },
            x.view(),
            dy.view(),
        )
        .unwrap();
        assert!(rep.passes(1e-12), "divergence {name}: {rep:?}");
        let wshape = vorticity(&scene, x0.view(), x1.view()).unwrap().dim();
        let wy: ArrayD<f64> = test_array(&[wshape.0 * wshape.1], 75);
        let rep = check_adjoint(
            |x| {
                let a = unpack(&x.to_owned(), &shapes);
                pack(&[&vorticity(&scene, a[0].view(), a[1].view()).unwrap()])
            },
            |y| {
                let a = unpack(&y.to_owned(), &[[wshape.0, wshape.1]]);
                let (p, q) = vorticity_vjp(&scene, a[0].view()).unwrap();
                pack(&[&p, &q])
            },
            x.view(),
            wy.view(),
        )
        .unwrap();
        assert!(rep.passes(1e-12), "vorticity {name}: {rep:?}");
    }
}

#[test]
fn force_is_zero_without_obstacle_and_pressure_pushes_downstream() {
    let scene = common::cavity().build().unwrap();
    let (ux, uy) = velocity(&scene, 1.0, 81);
    let p = Array2::<f64>::ones((6, 6));
    let f = obstacle_force(scene.force_weights(), ux.view(), uy.view(), p.view(), 0.1).unwrap();
    assert_eq!(f.to_vec(), vec![0.0, 0.0]);
    // a pressure high on the left of the cylinder only pushes it along +x
    let scene = common::channel().build().unwrap();
    let g = scene.grid();
    let p = Array2::from_shape_fn((g.nx, g.ny), |(i, _)| if i < 4 { 1.0 } else { 0.0 });
    let zx = Array2::<f64>::zeros((g.shape_x()[0], g.shape_x()[1]));
    let zy = Array2::<f64>::zeros((g.shape_y()[0], g.shape_y()[1]));
    let f = obstacle_force(scene.force_weights(), zx.view(), zy.view(), p.view(), 0.1).unwrap();
    assert!(f[0] > 0.0 && f[1].abs() < 1e-14, "{f:?}");
}
