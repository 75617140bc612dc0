//! A fixed workload of the periodic MacCormack velocity advection, for
//! timing and profiling its forward and its vector–Jacobian product alone.
//!
//! ```sh
//! cargo run --release -p diffphys-flow --example maccormack_cost -- fwd 128 200  # forward
//! cargo run --release -p diffphys-flow --example maccormack_cost -- fb 128 200   # forward + product
//! ```
//!
//! The Taylor–Green field plus a perturbation on a periodic `n × n` box of
//! side 2π in f32, the limiter on, dt at Courant number ½; the calls repeat
//! on the same inputs. Prints the milliseconds per call (wall) and a
//! checksum; `perf stat -e task-clock` around it gives the CPU time, which a
//! shared machine disturbs less than the wall time.

use std::time::Instant;

use diffphys_flow::advection::{advect_velocity, advect_velocity_vjp};
use diffphys_flow::{Advection, Faces, FlowGrid, Sides};
use ndarray::{Array1, Array2};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let mode = args.get(1).map_or("fb", String::as_str).to_owned();
    let n: usize = args.get(2).map_or(Ok(128), |s| s.parse())?;
    let calls: usize = args.get(3).map_or(Ok(100), |s| s.parse())?;
    let h = 2.0 * std::f64::consts::PI / n as f64;
    let grid = FlowGrid {
        nx: n,
        ny: n,
        dx: h,
        dy: h,
        sides: Sides::periodic(),
    };
    let faces = Faces::classify(&grid, &Array2::from_elem((n, n), false));
    let scheme = Advection::MacCormack { limiter: true };
    let dt = 0.5 * h;
    let wobble = |a: usize, b: usize| 0.3 * (((a * 7 + b * 13) % 17) as f64 / 17.0 - 0.5);
    let ux = Array2::from_shape_fn(grid.shape_x(), |(a, b)| {
        let (x, y) = (a as f64 * h, (b as f64 + 0.5) * h);
        (x.sin() * y.cos() + wobble(a, b)) as f32
    });
    let uy = Array2::from_shape_fn(grid.shape_y(), |(a, b)| {
        let (x, y) = ((a as f64 + 0.5) * h, b as f64 * h);
        (-x.cos() * y.sin() + wobble(b, a)) as f32
    });
    let walls = Array1::<f32>::zeros(4);
    let u = (ux.view(), uy.view());
    let mut sum = 0.0f64;
    let start = Instant::now();
    for _ in 0..calls {
        let (ax, ay) = advect_velocity(&grid, &faces, scheme, dt, u, u, walls.view())?;
        if mode == "fb" {
            let g = advect_velocity_vjp(
                &grid,
                &faces,
                scheme,
                dt,
                u,
                u,
                walls.view(),
                (ax.view(), ay.view()),
            )?;
            sum += f64::from(g.ux[[1, 2]]) + f64::from(g.uy[[3, 4]]);
        } else {
            sum += f64::from(ax[[1, 2]]) + f64::from(ay[[3, 4]]);
        }
    }
    let ms = start.elapsed().as_secs_f64() * 1e3 / calls as f64;
    println!("{{\"mode\":\"{mode}\",\"n\":{n},\"calls\":{calls},\"ms_per_call\":{ms},\"checksum\":{sum}}}");
    Ok(())
}
