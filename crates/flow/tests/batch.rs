//! Batches of states as fields, each sample at its own viscosity: every sample
//! steps as the scene steps it alone, on a tape and without, the gradient
//! through two batched steps (fields and viscosities) matches central finite
//! differences, and bad batches are typed errors.

mod common;

use common::channel;
use diffphys_flow::{FlowError, FlowParams, Scene, Splitting};
use diffphys_tape::{check_gradient, test_array, ArrayD, GradCheckOptions, Tape, Var};
use ndarray::{Array1, Axis};

/// Two samples' fields, stacked: a velocity of order one, a pressure.
fn batch(scene: &Scene) -> Vec<ArrayD<f64>> {
    scene
        .sample_shapes()
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let mut a = test_array::<f64>(&[2, s[0], s[1]], 10 + i as u64) * 0.4;
            if i == 0 {
                a += 0.8;
            }
            a
        })
        .collect()
}

fn viscosities() -> Array1<f64> {
    Array1::from(vec![0.05, 0.02])
}

#[test]
fn each_sample_steps_as_the_scene_steps_it_alone() {
    for splitting in [Splitting::Plain, Splitting::Incremental] {
        let scene = channel().splitting(splitting).build().unwrap();
        let fields = batch(&scene);
        assert_eq!(fields.len(), scene.batch_fields());
        let views: Vec<_> = fields.iter().map(|f| f.view()).collect();
        let nu = viscosities();
        let plain = scene.forward_batch(&views, nu.view().into_dyn()).unwrap();
        let tape = Tape::new();
        let vars: Vec<Var<'_, f64>> = fields.iter().map(|f| tape.var(f.clone())).collect();
        let recorded = scene
            .step_batch(&vars, tape.var(nu.clone().into_dyn()))
            .unwrap();
        for b in 0..2 {
            let sample: Vec<_> = fields.iter().map(|f| f.index_axis(Axis(0), b)).collect();
            let params = FlowParams {
                viscosity: nu[b],
                ..scene.params()
            };
            let (alone, _) = scene
                .forward(&scene.state_of(&sample).unwrap(), &params)
                .unwrap();
            for (f, expected) in scene.sample_of(&alone).iter().enumerate() {
                assert_eq!(
                    &plain[f].index_axis(Axis(0), b),
                    expected,
                    "{splitting:?} {f}"
                );
                let on_tape = recorded[f].to_array();
                assert_eq!(
                    &on_tape.index_axis(Axis(0), b),
                    expected,
                    "{splitting:?} {f}"
                );
            }
        }
        // The two samples differ (their viscosities do), so nothing was shared.
        assert_ne!(
            plain[0].index_axis(Axis(0), 0),
            plain[0].index_axis(Axis(0), 1)
        );
    }
}

#[test]
fn gradients_through_two_batched_steps_match_finite_differences() {
    for splitting in [Splitting::Plain, Splitting::Incremental] {
        let scene = channel().splitting(splitting).build().unwrap();
        let mut inputs = batch(&scene);
        inputs.push(viscosities().into_dyn());
        let n = scene.batch_fields();
        let weights: Vec<ArrayD<f64>> = inputs[..n]
            .iter()
            .enumerate()
            .map(|(i, f)| test_array(f.shape(), 40 + i as u64))
            .collect();
        let report = check_gradient(
            |tape, v| {
                let mut fields = v[..n].to_vec();
                for _ in 0..2 {
                    fields = scene.step_batch(&fields, v[n]).map_err(to_tape)?;
                }
                let mut loss = tape.scalar(0.0);
                for (f, w) in fields.iter().zip(&weights) {
                    loss = loss.add(f.mul(tape.constant(w.clone()))?.sum()?)?;
                }
                Ok(loss)
            },
            &inputs,
            GradCheckOptions::for_type::<f64>(),
        )
        .unwrap();
        assert!(report.passed, "{splitting:?}: {report:?}");
        assert!(report.entries > 100, "{splitting:?}: {}", report.entries);
    }
}

fn to_tape(e: FlowError) -> diffphys_tape::TapeError {
    diffphys_tape::TapeError::invalid("batched step", e.to_string())
}

#[test]
fn bad_batches_are_typed_errors() {
    let scene = channel().build().unwrap();
    let fields = batch(&scene);
    let views: Vec<_> = fields.iter().map(|f| f.view()).collect();
    let nu = viscosities().into_dyn();
    let shape_error = |r: Result<Vec<ArrayD<f64>>, FlowError>| {
        assert!(matches!(r, Err(FlowError::Shape { .. })), "{r:?}");
    };
    // Too few fields: the incremental scene carries its pressure.
    shape_error(scene.forward_batch(&views[..2], nu.view()));
    // A field of another shape.
    let wide = ArrayD::zeros(vec![2, 14, 6]);
    shape_error(scene.forward_batch(
        &[wide.view(), views[1].clone(), views[2].clone()],
        nu.view(),
    ));
    // Viscosities for another batch.
    let three = ArrayD::from_elem(vec![3], 0.05);
    shape_error(scene.forward_batch(&views, three.view()));
    let tape = Tape::new();
    let vars: Vec<_> = fields.iter().map(|f| tape.var(f.clone())).collect();
    let r = scene.step_batch(&vars, tape.var(ArrayD::from_elem(vec![2, 1], 0.05)));
    assert!(matches!(r, Err(FlowError::Shape { .. })), "{r:?}");
    // Scalars are not carried.
    let with_scalar = channel().scalars(1).build().unwrap();
    let r = with_scalar.forward_batch(&views, nu.view());
    assert!(matches!(r, Err(FlowError::InvalidScene { .. })), "{r:?}");
    let e = scene.forward_batch(&views[..2], nu.view()).unwrap_err();
    assert!(e.to_string().contains("fields"), "{e}");
}
