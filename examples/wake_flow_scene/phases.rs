//! The phases of `wake_flow`'s study for one data seed: the reference, the
//! untrained baselines, the trainings, selection and the held-out split, and
//! the speed study. Declared by the example itself (not by the scene module,
//! which the tests include).

use super::*;

/// Phase 1: the three splits of data seed `ds`, the reference generated or
/// read from the cache.
pub(crate) fn references(ctx: &Ctx, ds: u64) -> Result<Splits<Vec<Reference>>, BoxError> {
    let Ctx {
        options,
        sizes,
        coarse,
        fine,
        cache,
        ..
    } = ctx;
    let threads = ctx.threads;
    // Phase 1: the reference (cached).
    let total = 3 * sizes.warm_base
        + (options.train_re.len() + options.validation_re.len() + options.held_out_re.len())
            * (sizes.warm + sizes.record);
    let bar = progress_bar(total, &format!("data {ds}: reference"));
    let t0 = Instant::now();
    let splits = Splits::generate(
        DataSeed(ds),
        [
            options.train_re.len(),
            options.validation_re.len(),
            options.held_out_re.len(),
        ],
        |split, _, rng| {
            let list = match split {
                Split::Train => &options.train_re,
                Split::Validation => &options.validation_re,
                Split::HeldOut => &options.held_out_re,
            };
            let mut run = || -> Result<Vec<Reference>, BoxError> {
                let bump = Bump::draw(rng);
                let tick = |n| bar.inc(n);
                let base = base_state(cache, sizes, fine, bump, &tick)?;
                // The Reynolds numbers of a split share the workers.
                Ok(run_jobs(list, threads, |&re| {
                    reference(cache, sizes, coarse.scene(), fine, (&base, bump), re, &tick)
                        .map_err(|e| e.to_string())
                })?)
            };
            run().map_err(|e| diffphys::learn::LearnError::Invalid {
                what: "reference",
                message: e.to_string(),
            })
        },
    )?;
    bar.finish_and_clear();
    mem("reference");
    println!(
        "data seed {ds}: reference ready in {:.1} s (cached under {})",
        t0.elapsed().as_secs_f64(),
        cache.dir().display()
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
        options,
        sizes,
        coarse,
        ..
    } = ctx;
    let new_net = |size, seed| ctx.new_net(size, seed);
    let mut speed = Value::Null;
    let mut pressure = Value::Null;
    if let (true, Some((splits, probe))) = (options.speed, speed_inputs) {
        let size = probe.as_ref().map_or(MAIN_SIZE, |p| p.1);
        let (net0, _) = new_net(size, 0)?;
        let hybrid: Wake = Hybrid::new(coarse.clone(), net0);
        let params = probe.as_ref().map(|p| &p.0);
        let speed_on =
            |refs: &[Reference]| study::speed(&hybrid, params, refs, sizes, &ctx.args.out);
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
        pressure = study::pressure_solves(sizes, options.validation_re[0])?;
    }

    Ok((speed, pressure))
}
