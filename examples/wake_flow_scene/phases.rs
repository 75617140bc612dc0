//! The phases of `wake_flow`'s study for one data seed: the reference, the
//! untrained baselines, the trainings, selection and the held-out split, and
//! the speed study. Declared by the example itself (not by the scene module,
//! which the tests include).

use super::*;

/// Phase 1: the three splits of data seed `ds`, the reference generated or
/// read from the cache.
pub(crate) fn references(ctx: &Ctx, ds: u64) -> Result<Splits<Vec<Reference>>, BoxError> {
    let o = &ctx.options;
    let t0 = Instant::now();
    let scenes = (ctx.coarse.scene(), &ctx.fine);
    let re = [&o.train_re[..], &o.validation_re, &o.held_out_re];
    let splits = ctx.wake.splits(&ctx.cache, scenes, ds, re, ctx.threads)?;
    mem("reference");
    println!(
        "data seed {ds}: reference ready in {:.1} s (cached under {})",
        t0.elapsed().as_secs_f64(),
        ctx.cache.dir().display()
    );
    Ok(splits)
}

/// Phase 6: speed against accuracy on the first data seed's held-out split
/// (a baseline reading), and the pressure solves inside a rollout.
pub(crate) fn speed_study(
    ctx: &Ctx,
    speed_inputs: Option<&(Splits<Vec<Reference>>, Option<Probe>)>,
    rec: &mut Record,
) -> Result<(Value, Value), BoxError> {
    let Ctx {
        options, coarse, ..
    } = ctx;
    let new_net = |size, seed| ctx.new_net(size, seed);
    let mut speed = Value::Null;
    let mut pressure = Value::Null;
    if let (true, Some((splits, probe))) = (options.speed, speed_inputs) {
        let size = probe.as_ref().map_or(MAIN_SIZE, |p| p.1);
        let (net0, _) = new_net(size, 0)?;
        let hybrid: Hybrids = Hybrid::new(coarse.clone(), net0);
        let params = probe.as_ref().map(|p| &p.0);
        let speed_on = |refs: &[Reference]| ctx.wake.speed(&hybrid, params, refs, &ctx.args.out);
        speed = if ctx.validation_only {
            speed_on(&splits.validation)?
        } else {
            let result = splits.held_out().evaluate_baseline(|refs| {
                speed_on(refs).map_err(|e| diffphys::learn::LearnError::Invalid {
                    what: "speed",
                    message: e.to_string(),
                })
            })?;
            rec.log
                .held_out_readings
                .insert(splits.seed.0, splits.held_out().readings());
            result
        };
        mem("speed");
        pressure = ctx.wake.pressure_solves(options.validation_re[0])?;
    }

    Ok((speed, pressure))
}
