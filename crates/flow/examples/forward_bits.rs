//! Fingerprints of the flow step's results, for checking that a change to
//! its kernels keeps every bit, and a fixed forward workload to profile.
//!
//! ```sh
//! cargo run --release -p diffphys-flow --example forward_bits            # the fingerprints
//! cargo run --release -p diffphys-flow --example forward_bits -- box 128 20  # 20 plain steps
//! cargo run --release -p diffphys-flow --example forward_bits -- wake 128 20 # the wake, 128 x 256
//! ```
//!
//! The fingerprints are FNV-1a hashes of the bits of the final state of
//! several rollouts (the periodic box in f32 and f64 with MacCormack and
//! semi-Lagrangian advection, the DFG cylinder channel, the lid-driven
//! cavity) and of the gradients of `½|u_end|²` through short taped rollouts.
//! Two builds that print the same lines computed the same numbers.

use diffphys_flow::validation::{pbdl_wake, Cavity, DfgChannel};
use diffphys_flow::{Advection, Buoyancy, FlowState, FlowVars, ParamVars, Scene, TaylorGreen};
use diffphys_tape::{Real, Tape};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// FNV-1a over the bits of every value.
fn fingerprint<T: Real>(arrays: &[&ndarray::Array2<T>]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for a in arrays {
        for v in a.iter() {
            for byte in v.as_f64().to_bits().to_le_bytes() {
                h ^= u64::from(byte);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    h
}

fn state_print<T: Real>(s: &FlowState<T>) -> u64 {
    let mut all = vec![&s.ux, &s.uy, &s.pressure];
    all.extend(s.scalars.iter());
    fingerprint(&all)
}

fn taylor_green_box(n: usize, advection: Advection) -> Result<Scene> {
    let tg = TaylorGreen {
        amplitude: 1.0,
        viscosity: 1e-3,
    };
    let h = 2.0 * std::f64::consts::PI / n as f64;
    Ok(tg.scene(n, 0.5 * h, advection).build()?)
}

fn start<T: Real>(scene: &Scene) -> FlowState<T> {
    let tg = TaylorGreen {
        amplitude: 1.0,
        viscosity: 1e-3,
    };
    // a perturbed start, so that the limiter and every branch act
    let mut s = tg.state::<T>(scene, 0.0);
    s.ux.indexed_iter_mut().for_each(|((a, b), v)| {
        *v += T::from_f64(0.3 * (((a * 7 + b * 13) % 17) as f64 / 17.0 - 0.5));
    });
    s
}

fn rollout<T: Real>(scene: &Scene, s: FlowState<T>, steps: usize) -> Result<FlowState<T>> {
    let params = scene.params::<T>();
    let mut s = s;
    for _ in 0..steps {
        s = scene.forward(&s, &params)?.0;
    }
    Ok(s)
}

/// The gradient of `½|u_end|²` by the start velocity through `steps` taped steps.
fn gradient<T: Real>(scene: &Scene, s: &FlowState<T>, steps: usize) -> Result<u64> {
    let tape = Tape::<T>::new();
    let v0 = FlowVars::variables(&tape, s);
    let p = ParamVars::constants(&tape, &scene.params::<T>());
    let mut v = v0.clone();
    for _ in 0..steps {
        v = scene.step(&tape, &v, &p)?.0;
    }
    let loss =
        v.ux.dot(v.ux)?
            .add(v.uy.dot(v.uy)?)?
            .mul_scalar(T::from_f64(0.5))?;
    let g = tape.backward(loss, &[v0.ux, v0.uy])?;
    let two = |x: diffphys_tape::Var<'_, T>| -> Result<ndarray::Array2<T>> {
        Ok(g.get(x).expect("requested").clone().into_dimensionality()?)
    };
    Ok(fingerprint(&[&two(v0.ux)?, &two(v0.uy)?]))
}

/// The PBDL wake flow of `benches/flow_peers` at `res` x `2 res` cells
/// ([`pbdl_wake`]), with a passive scalar that drives a buoyancy.
fn wake(res: usize, advection: Advection) -> Result<Scene> {
    Ok(pbdl_wake(res)
        .advection(advection)
        .scalars(1)
        .buoyancy(Buoyancy {
            beta: 0.01,
            scalar: 0,
        })
        .build()?)
}

fn wake_start<T: Real>(scene: &Scene) -> FlowState<T> {
    let g = scene.grid();
    let mut s = FlowState::zeros(scene);
    s.uy.fill(T::one());
    s.scalars[0] = ndarray::Array2::from_shape_fn(g.cell_shape(), |(a, b)| {
        T::from_f64(((a * 5 + b * 3) % 11) as f64 / 11.0)
    });
    s
}

fn fingerprints() -> Result<()> {
    let mut all: Vec<(String, u64)> = Vec::new();
    let mut put = |label: String, hash: u64| {
        println!("{label}: {hash:016x}");
        all.push((label, hash));
    };
    for (name, advection) in [
        ("semi-lagrangian", Advection::SemiLagrangian),
        ("maccormack", Advection::MacCormack { limiter: true }),
    ] {
        let scene = wake(32, advection)?;
        let f32s = rollout(&scene, wake_start::<f32>(&scene), 100)?;
        let f64s = rollout(&scene, wake_start::<f64>(&scene), 100)?;
        put(format!("wake 32 {name} f32 100 steps"), state_print(&f32s));
        put(format!("wake 32 {name} f64 100 steps"), state_print(&f64s));
        let g = gradient(&scene, &f64s, 5)?;
        put(format!("wake 32 {name} f64 gradient, 5 steps"), g);
    }
    let mac = Advection::MacCormack { limiter: true };
    for (name, advection) in [
        ("maccormack", mac),
        (
            "maccormack-unlimited",
            Advection::MacCormack { limiter: false },
        ),
        ("semi-lagrangian", Advection::SemiLagrangian),
    ] {
        let scene = taylor_green_box(128, advection)?;
        let f32s = rollout(&scene, start::<f32>(&scene), 200)?;
        let f64s = rollout(&scene, start::<f64>(&scene), 200)?;
        put(format!("box 128 {name} f32 200 steps"), state_print(&f32s));
        put(format!("box 128 {name} f64 200 steps"), state_print(&f64s));
        let small = taylor_green_box(32, advection)?;
        let g = gradient(&small, &start::<f64>(&small), 10)?;
        put(format!("box 32 {name} f64 gradient, 10 steps"), g);
    }
    let channel = DfgChannel::new(8)?;
    let scene = channel.scene(1.5)?;
    let s = rollout(&scene, DfgChannel::start(&scene), 300)?;
    put("cylinder cpd 8, 300 steps".to_string(), state_print(&s));
    let g = gradient(&scene, &DfgChannel::start(&scene), 5)?;
    put("cylinder cpd 8 gradient, 5 steps".to_string(), g);
    let scene = Cavity::new(100, 48)?.scene()?;
    let s = rollout(&scene, FlowState::<f64>::zeros(&scene), 300)?;
    put("cavity Re 100 48^2, 300 steps".to_string(), state_print(&s));
    let g = gradient(&scene, &s, 5)?;
    put("cavity Re 100 48^2 gradient, 5 steps".to_string(), g);
    let entries: Vec<String> = all
        .iter()
        .map(|(label, hash)| format!("\"{label}\":\"{hash:016x}\""))
        .collect();
    println!(
        "{{\"example\":\"forward_bits\",\"fingerprints\":{{{}}}}}",
        entries.join(",")
    );
    Ok(())
}

/// The timing's figures, then its JSON line.
fn timing_line(scene: &str, n: usize, ms: f64, hash: u64) {
    println!("{scene} {n} f32: {ms:.3} ms per step ({hash:016x})");
    println!(
        "{{\"example\":\"forward_bits\",\"scene\":\"{scene}\",\"n\":{n},\"ms_per_step\":{ms},\"fingerprint\":\"{hash:016x}\"}}"
    );
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.as_slice() {
        [] => fingerprints(),
        [scene, n, steps] if scene == "box" => {
            let n: usize = n.parse()?;
            let steps: usize = steps.parse()?;
            let scene = taylor_green_box(n, Advection::MacCormack { limiter: true })?;
            let tg = TaylorGreen {
                amplitude: 1.0,
                viscosity: 1e-3,
            };
            let s = tg.state::<f32>(&scene, 0.0);
            // one step outside the measured part (first-touch of buffers)
            let s = rollout(&scene, s, 1)?;
            let t = std::time::Instant::now();
            let s = rollout(&scene, s, steps)?;
            let ms = t.elapsed().as_secs_f64() * 1e3 / steps as f64;
            timing_line("box", n, ms, state_print(&s));
            Ok(())
        }
        [scene, n, steps] if scene == "wake" => {
            let n: usize = n.parse()?;
            let scene = wake(n, Advection::SemiLagrangian)?;
            let steps: usize = steps.parse()?;
            let s = rollout(&scene, wake_start::<f32>(&scene), 1)?;
            let t = std::time::Instant::now();
            let s = rollout(&scene, s, steps)?;
            let ms = t.elapsed().as_secs_f64() * 1e3 / steps as f64;
            timing_line("wake", n, ms, state_print(&s));
            Ok(())
        }
        _ => Err("usage: forward_bits [box|wake N STEPS]".into()),
    }
}
