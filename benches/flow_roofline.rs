//! The periodic box's step operator by operator, against its memory-traffic
//! floor (issue 45, docs/08 "Sixth round: the step's roofline"): JAX-CFD's
//! Taylor–Green box at 128², 256² and 512², f32 state, MacCormack with the
//! limiter and the Fourier pressure solve, each of the step's four operators
//! alone, forward and vector–Jacobian product, with the scene's own pieces.
//!
//! Throughput is set to the bytes each operator must move at least (read its
//! inputs once, write its outputs once, in f32), so the GiB/s criterion
//! prints divided by the stream bandwidth of `benches/bandwidth.rs` is the
//! fraction of the roofline that operator reaches:
//!
//! | operator | forward: read → written | B/cell | product: read → written | B/cell |
//! | --- | --- | ---: | --- | ---: |
//! | `subtract_pressure_gradient` | u_x, u_y, P → u_x, u_y | 20 | g_x, g_y → g_P (the identity part passed on) | 12 |
//! | `advect_velocity` | q_x, q_y, u_x, u_y → 2 | 24 | q, u, g (2 each) → g_q, g_u (2 each) | 40 |
//! | `diffuse` (explicit) | u_x, u_y → 2 | 16 | g_x, g_y, u_x, u_y → g_x, g_y, ∂ν | 24 |
//! | `project` (Fourier) | u_x, u_y → u_x, u_y, P | 20 | g_x, g_y, g_P → g_x, g_y | 20 |
//!
//! (The product of the diffusion reads `u` for `∂L/∂ν = dt ⟨g, L u⟩`.) Run:
//! `cargo bench --bench flow_roofline` (`RAYON_NUM_THREADS=1` for one core).

#[path = "../examples/flow_common/mod.rs"]
mod flow_common;

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffphys::flow::advection::{advect_velocity, advect_velocity_vjp};
use diffphys::flow::diffusion::{diffuse, diffuse_vjp};
use diffphys::flow::pressure::{
    project, project_vjp, subtract_pressure_gradient, subtract_pressure_gradient_vjp,
};
use diffphys::flow::{Advection, ViscosityMode};
use ndarray::Array1;

/// Bytes per cell each operator must move at least, f32: (forward, product).
const FLOOR: [(&str, u64, u64); 4] = [
    ("pressure_gradient", 20, 12),
    ("advection", 24, 40),
    ("diffusion", 16, 24),
    ("projection", 20, 20),
];

fn floor(name: &str) -> (u64, u64) {
    let row = FLOOR
        .iter()
        .find(|(n, ..)| *n == name)
        .expect("a listed operator");
    (row.1, row.2)
}

fn operators(c: &mut Criterion) {
    for n in [128, 256, 512] {
        let (scene, start) = flow_common::box_scene::<f32>(n, None).expect("the box builds");
        let (grid, faces) = (scene.grid(), scene.faces());
        let (system, diffusion) = (scene.pressure_system(), scene.diffusion());
        let dt = scene.dt();
        let nu = scene.viscosity() as f32;
        let walls = Array1::<f32>::zeros(4);
        let (ux, uy, p) = (start.ux.view(), start.uy.view(), start.pressure.view());
        let cells = (n * n) as u64;
        let mut g = c.benchmark_group(format!("flow_roofline_box_f32_{n}"));
        g.warm_up_time(Duration::from_millis(500));
        if n > 256 {
            g.sample_size(20);
        }
        let mut bench = |name: &str, product: bool, run: &mut dyn FnMut()| {
            let (fwd, vjp) = floor(name);
            g.throughput(Throughput::Bytes(cells * if product { vjp } else { fwd }));
            let id = BenchmarkId::new(name, if product { "product" } else { "forward" });
            g.bench_function(id, |b| b.iter(&mut *run));
        };

        let c_grad = 0.5 * dt;
        bench("pressure_gradient", false, &mut || {
            black_box(subtract_pressure_gradient(grid, faces, c_grad, ux, uy, p).expect("runs"));
        });
        bench("pressure_gradient", true, &mut || {
            let r = subtract_pressure_gradient_vjp(grid, faces, c_grad, ux, uy);
            black_box(r.expect("runs"));
        });

        let scheme = Advection::MacCormack { limiter: true };
        let advect = || {
            advect_velocity(grid, faces, scheme, dt, (ux, uy), (ux, uy), walls.view())
                .expect("the advection runs")
        };
        bench("advection", false, &mut || {
            black_box(advect());
        });
        let (ax, ay) = advect();
        bench("advection", true, &mut || {
            let w = walls.view();
            let grads = (ax.view(), ay.view());
            let r = advect_velocity_vjp(grid, faces, scheme, dt, (ux, uy), (ux, uy), w, grads);
            black_box(r.expect("the product runs"));
        });

        let mode = ViscosityMode::Explicit;
        let (dx, dy) = diffuse(diffusion, mode, dt, ux, uy, nu, walls.view()).expect("runs");
        bench("diffusion", false, &mut || {
            black_box(diffuse(diffusion, mode, dt, ux, uy, nu, walls.view()).expect("runs"));
        });
        bench("diffusion", true, &mut || {
            let out = (dx.view(), dy.view());
            let r = diffuse_vjp(diffusion, mode, dt, ux, uy, nu, walls.view(), out, (ux, uy));
            black_box(r.expect("runs"));
        });

        let tau = 0.5 * dt;
        bench("projection", false, &mut || {
            black_box(project(system, tau, ux, uy, None).expect("the projection runs"));
        });
        bench("projection", true, &mut || {
            black_box(project_vjp(system, tau, ux, uy, Some(p)).expect("the product runs"));
        });
        g.finish();
    }
}

criterion_group!(benches, operators);
criterion_main!(benches);
