//! Checkpointing: the gradients of a checkpointed unroll are those of the full
//! tape, nesting works, the tape holds less, and errors name their step.

use std::rc::Rc;

use diffphys_tape::{
    check_gradient, checkpointed_steps, test_array, ArrayD, GradCheckOptions, Schedule, SegmentFn,
    StepFn, Tape, TapeError, Var,
};

const N: usize = 12;

/// A nonlinear step with two parameters and a running loss in the state:
/// `u ← tanh(a ⊙ u + roll(u, 1)) + b`, `loss ← loss + Σ u²/N`.
fn step() -> Rc<StepFn<f64>> {
    Rc::new(|_tape, _k, s, p| {
        let u = p[0].mul(s[0])?.add(s[0].roll(1, 0)?)?.tanh()?.add(p[1])?;
        let loss = s[1].add(u.mul(u)?.mean()?)?;
        Ok(vec![u, loss])
    })
}

/// Final loss and the gradients of `(u₀, a, b)` for an unroll stored by `schedule`,
/// with the tape's peak bytes.
fn gradients(schedule: Schedule, steps: usize) -> (f64, Vec<ArrayD<f64>>, usize) {
    let tape = Tape::<f64>::new();
    let u0 = tape.var(test_array(&[N], 1));
    let a = tape.var(test_array::<f64>(&[N], 2).mapv(|v| 0.9 + 0.2 * v));
    let b = tape.var(test_array::<f64>(&[N], 3).mapv(|v| 0.1 * v));
    let loss0 = tape.scalar(0.0);
    let out = checkpointed_steps(&tape, schedule, steps, &[u0, loss0], &[a, b], step()).unwrap();
    let grads = tape.backward(out[1], &[u0, a, b]).unwrap();
    let g = [u0, a, b]
        .iter()
        .map(|v| grads.get(*v).unwrap().clone())
        .collect();
    (out[1].item().unwrap(), g, tape.stats().peak_bytes)
}

fn max_abs_diff(a: &[ArrayD<f64>], b: &[ArrayD<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| p.iter().zip(q).map(|(x, y)| (x - y).abs()))
        .fold(0.0, f64::max)
}

#[test]
fn checkpointed_gradients_equal_the_full_tape() {
    let steps = 50;
    let (loss, full, full_bytes) = gradients(Schedule::Full, steps);
    for schedule in [
        Schedule::Every(1),
        Schedule::Every(7), // does not divide 50
        Schedule::Every(10),
        Schedule::Every(64), // one segment
        Schedule::Nested { branches: 2 },
        Schedule::Nested { branches: 4 },
    ] {
        let (l, g, bytes) = gradients(schedule, steps);
        assert_eq!(l.to_bits(), loss.to_bits(), "{schedule:?}");
        let diff = max_abs_diff(&g, &full);
        assert!(diff <= 1e-12, "{schedule:?}: {diff:e}");
        if schedule != Schedule::Every(1) {
            assert!(
                bytes * 3 < full_bytes,
                "{schedule:?}: {bytes} vs {full_bytes}"
            );
        }
    }
}

#[test]
fn checkpointed_unrolls_leave_no_recomputed_steps_in_the_pool() {
    // Steps of 4096 entries (above the pool's minimum length), 256 of them: the
    // full tape keeps every step; a checkpointed unroll's scratch tapes must not
    // leave their buffers in the outer tape's pool (before the scratch tapes had
    // pools of their own, the pool held 2.5x the full tape's peak after the sweep).
    let steps = 256;
    let held = |schedule: Schedule| {
        let tape = Tape::<f64>::new();
        let u0 = tape.var(test_array(&[4096], 1));
        let a = tape.var(test_array::<f64>(&[4096], 2).mapv(|v| 0.9 + 0.2 * v));
        let b = tape.var(test_array::<f64>(&[4096], 3).mapv(|v| 0.1 * v));
        let loss0 = tape.scalar(0.0);
        let out =
            checkpointed_steps(&tape, schedule, steps, &[u0, loss0], &[a, b], step()).unwrap();
        tape.backward(out[1], &[u0, a, b]).unwrap();
        (tape.pool().held_bytes(), tape.stats().peak_bytes)
    };
    let (_, full_bytes) = held(Schedule::Full);
    for schedule in [Schedule::Every(16), Schedule::Nested { branches: 4 }] {
        let (pool_bytes, tape_bytes) = held(schedule);
        assert!(
            (pool_bytes + tape_bytes) * 10 < full_bytes,
            "{schedule:?}: pool {pool_bytes} + tape {tape_bytes} bytes vs the full tape's {full_bytes}"
        );
    }
}

#[test]
fn the_checkpointed_gradient_passes_finite_differences() {
    let report = check_gradient(
        |tape, v| {
            let zero = tape.scalar(0.0);
            let out = checkpointed_steps(
                tape,
                Schedule::Every(3),
                8,
                &[v[0], zero],
                &[v[1], v[2]],
                step(),
            )?;
            Ok(out[1])
        },
        &[
            test_array(&[N], 4),
            test_array::<f64>(&[N], 5).mapv(|v| 0.9 + 0.2 * v),
            test_array(&[N], 6),
        ],
        GradCheckOptions::for_type::<f64>(),
    )
    .unwrap();
    assert!(report.passed, "{report:?}");
}

#[test]
fn checkpoints_nest() {
    // A checkpoint whose closure checkpoints again and calls the stepped unroll.
    let inner: Rc<SegmentFn<f64>> = Rc::new(|tape, v| {
        let sq: Rc<SegmentFn<f64>> = Rc::new(|_, w| Ok(vec![w[0].mul(w[0])?.sin()?]));
        let y = tape.checkpoint("square", sq, &[v[0]])?;
        let zero = tape.scalar(0.0);
        checkpointed_steps(
            tape,
            Schedule::Every(2),
            5,
            &[y[0], zero],
            &[v[1], v[2]],
            step(),
        )
    });
    let run = |nested: bool| {
        let tape = Tape::<f64>::new();
        let vars: Vec<Var<'_, f64>> = (0..3).map(|k| tape.var(test_array(&[N], 10 + k))).collect();
        let out = if nested {
            tape.checkpoint("outer", Rc::clone(&inner), &vars).unwrap()
        } else {
            let y = vars[0].mul(vars[0]).unwrap().sin().unwrap();
            let zero = tape.scalar(0.0);
            checkpointed_steps(&tape, Schedule::Full, 5, &[y, zero], &vars[1..], step()).unwrap()
        };
        let grads = tape.backward(out[1], &vars).unwrap();
        vars.iter()
            .map(|v| grads.get(*v).unwrap().clone())
            .collect::<Vec<_>>()
    };
    let diff = max_abs_diff(&run(true), &run(false));
    assert!(diff <= 1e-12, "{diff:e}");
}

/// `u ← 0.9 u + 0.1 √(c_k (u² + 1))`, with `c_7 = 0`: fine forward, an infinite
/// derivative of the square root at step 7 (and only there) backward.
fn kinked_step() -> Rc<StepFn<f64>> {
    Rc::new(|_, k, s, _| {
        let c = if k == 7 { 0.0 } else { 1.0 };
        let root = s[0].mul(s[0])?.add_scalar(1.0)?.mul_scalar(c)?.sqrt()?;
        Ok(vec![s[0].mul_scalar(0.9)?.add(root.mul_scalar(0.1)?)?])
    })
}

#[test]
fn errors_in_a_segment_name_their_step() {
    // A step that fails in the forward pass.
    let failing: Rc<StepFn<f64>> = Rc::new(|_, k, s, _| {
        if k == 13 {
            Err(TapeError::invalid("my step", "CFL violated"))
        } else {
            Ok(s.to_vec())
        }
    });
    for schedule in [
        Schedule::Full,
        Schedule::Every(4),
        Schedule::Nested { branches: 3 },
    ] {
        let tape = Tape::<f64>::new();
        let u = tape.var(test_array(&[N], 1));
        let err =
            checkpointed_steps(&tape, schedule, 20, &[u], &[], Rc::clone(&failing)).unwrap_err();
        let message = err.to_string();
        assert!(
            message.contains("step 13") && message.contains("CFL violated"),
            "{schedule:?}: {message}"
        );
    }
    // A non-finite gradient in a recomputed segment's backward sweep.
    for schedule in [
        Schedule::Every(4),
        Schedule::Every(16),
        Schedule::Nested { branches: 2 },
    ] {
        let tape = Tape::<f64>::new();
        let u = tape.var(test_array(&[N], 1));
        let out = checkpointed_steps(&tape, schedule, 12, &[u], &[], kinked_step()).unwrap();
        let loss = out[0].sum().unwrap();
        let err = tape.backward(loss, &[u]).unwrap_err();
        let message = format!("{err}: {:?}", std::error::Error::source(&err));
        assert!(message.contains("step 7"), "{schedule:?}: {message}");
    }
}

#[test]
fn bad_schedules_and_states_are_errors() {
    let tape = Tape::<f64>::new();
    let u = tape.var(test_array(&[N], 1));
    for schedule in [Schedule::Every(0), Schedule::Nested { branches: 1 }] {
        let err = checkpointed_steps(&tape, schedule, 4, &[u], &[], step()).unwrap_err();
        assert!(matches!(err, TapeError::InvalidArgument { .. }), "{err:?}");
    }
    let grows: Rc<StepFn<f64>> = Rc::new(|_, _, s, _| Ok(vec![s[0], s[0]]));
    let err = checkpointed_steps(&tape, Schedule::Every(2), 4, &[u], &[], grows).unwrap_err();
    assert!(err.to_string().contains("expected 1"), "{err}");
}
