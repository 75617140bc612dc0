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

/// The training and validation trajectories of data seed `ds`, the noise
/// scale, the error on the faces the coarse step pins, and `src`'s validation.
pub(crate) fn untrained(
    ctx: &Ctx,
    ds: u64,
    splits: &Splits<Vec<Reference>>,
    rec: &mut Record,
) -> Result<(Vec<Trajectory>, Vec<Trajectory>, f64), BoxError> {
    let Ctx {
        options,
        sizes,
        coarse,
        ..
    } = ctx;
    let Record {
        log,
        sigma_used,
        pinned_face_error,
        ..
    } = rec;
    let new_net = |size, seed| ctx.new_net(size, seed);
    let train: Vec<Trajectory> = splits
        .train
        .iter()
        .map(|r| r.window(coarse.scene(), 0, r.states.len()))
        .collect::<Result<_, _>>()?;
    let validation: Vec<Trajectory> = splits
        .validation
        .iter()
        .map(|r| r.window(coarse.scene(), 0, sizes.rollout + 1))
        .collect::<Result<_, _>>()?;
    let sigma = coarse.one_step_rms(&train, 10)?;
    // What no corrector can remove: the pinned faces' error (train and
    // validation Re; the body decides it, see `Body`).
    let mut pinned = Vec::new();
    for (re, t) in options
        .train_re
        .iter()
        .zip(&train)
        .chain(options.validation_re.iter().zip(&validation))
    {
        pinned.push((*re, coarse.pinned_face_error(t)?));
    }
    println!(
        "  error on the faces the coarse step pins (no corrector removes it), per train and validation Re: {}",
        pinned
            .iter()
            .map(|(re, e)| format!("{re}: {e:.4}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    // The staircase and inscribed bodies make this zero by construction.
    if sizes.body != Body::Cylinder {
        if let Some(&(re, error)) = pinned.iter().find(|(_, e)| *e > 1e-12) {
            return Err(WakeError::PinnedFaces {
                body: sizes.body.label(),
                re,
                error,
            }
            .into());
        }
    }
    pinned_face_error.insert(
        format!("data_{ds}"),
        pinned
            .iter()
            .map(|(re, e)| (re.to_string(), json!(e)))
            .collect(),
    );
    *sigma_used = sigma;
    let (net0, _) = new_net(MAIN_SIZE, 0)?;
    let hybrid: Wake = Hybrid::new(coarse.clone(), net0);
    let src_val = rollout(&hybrid, None, &validation, sizes.rollout)?.mean();
    let src_per_re = rollout_each(&hybrid, None, &validation, sizes.rollout)?;
    let per_re: Vec<(String, f64)> = (options.validation_re.iter())
        .map(|re| re.to_string())
        .zip(src_per_re.iter().copied())
        .collect();
    log.baseline("src", ds, src_val, &per_re);
    println!("  noise sigma (one-step RMS error of the coarse solver) {sigma:.2e}; src validation {src_val:.4} (per Re {src_per_re:.4?})");

    mem("src");
    Ok((train, validation, sigma))
}

/// Phases 2 to 5 of data seed `ds`: the learning rates on validation, then
/// the library's protocol over the plan (every entry at every training seed,
/// selection on validation, each trained model once on the held-out split,
/// saved); the selected SOL corrector's parameters for the speed study.
pub(crate) fn protocol(
    ctx: &Ctx,
    ds: u64,
    splits: &Splits<Vec<Reference>>,
    (train, validation): (&[Trajectory], &[Trajectory]),
    sigma: f64,
    rec: &mut Record,
) -> Result<Option<Probe>, BoxError> {
    let Ctx {
        options,
        seeds,
        args,
        coarse,
        sizes,
        ..
    } = ctx;
    let corrector =
        |size: NetSize, seed: TrainSeed| ctx.new_net(size, seed.0).map_err(BoxError::from);
    let trainings = Trainings {
        simulator: coarse,
        corrector: &corrector,
        schedule: LrSchedule::Cosine {
            final_fraction: 0.1,
        },
        step_evaluations: STEP_EVALUATIONS,
        checkpoint: Some(4),
        validation_steps: sizes.rollout,
        validation_evaluations: args.pick(VALIDATION_EVALUATIONS, 32),
        sigma,
        train,
        validation,
        label: format!("data {ds}"),
    };
    // The learning rate of `non` (and `noise`) and of SOL, on validation:
    // pilots at a quarter of the budget, first training seed.
    let pilot = (
        MAIN_SIZE,
        TrainSeed(seeds.train[0]),
        ctx.evaluations.div_ceil(PILOT_DIVISOR),
    );
    let lrs = trainings.learning_rates(
        &options.variants,
        &options.learning_rates,
        pilot,
        ctx.threads,
    )?;
    lrs.record(ds, &mut rec.log.learning_rates);
    let plan = plan(options, seeds);
    let held_out_jobs = if ctx.validation_only {
        0
    } else {
        options.held_out_re.len() * (1 + plan.jobs().len())
    };
    let bar = progress_bar(held_out_jobs, &format!("data {ds}: held-out"));
    if !ctx.validation_only {
        let (src, reference_last) = baselines(ctx, splits, &bar)?;
        rec.results.record("src", ds, None, &src)?;
        rec.results
            .last
            .entry("reference".into())
            .or_insert(reference_last);
    }
    let train_job = |j: &learn_study::Job<Variant, NetSize>| {
        trainings.train(&TrainJob {
            variant: j.variant,
            size: j.size,
            seed: j.seed,
            lr: lrs.of(j.variant),
            evaluations: ctx.evaluations,
        })
    };
    // Selection on validation only: every SOL variant trained, at every
    // size, competes (the unroll and the corrector's size are both chosen
    // here); the others stand alone. Then the held-out split, each trained
    // model once.
    let protocol = Protocol {
        plan: &plan,
        threads: ctx.threads,
    };
    let score = |m: &Model| m.trained.model.validation;
    let competes = |e: &learn_study::Entry<Variant, NetSize>| matches!(e.variant, Variant::Sol(_));
    let outcomes: Vec<_> = if ctx.validation_only {
        let selected = protocol.select(train_job, score, competes)?;
        selected
            .into_iter()
            .map(|o| o.map_held_out(|()| None))
            .collect()
    } else {
        let evaluated = protocol.run(
            splits.held_out(),
            train_job,
            score,
            competes,
            |_, models, refs| {
                let models: Vec<_> = models
                    .iter()
                    .map(|m| (Some(&m.trained.model.params), m.job.size, m.job.seed.0))
                    .collect();
                held_out_runs(ctx, &models, refs, &bar)
            },
        )?;
        evaluated
            .into_iter()
            .map(|o| o.map_held_out(Some))
            .collect()
    };
    bar.finish_and_clear();
    mem("held-out");
    let conditions: Vec<String> = options.validation_re.iter().map(f64::to_string).collect();
    for &(variant, size) in &plan.entries {
        let entry = learn_study::Entry { variant, size };
        for o in outcomes.iter().filter(|o| o.entry == entry) {
            for r in &o.runs {
                rec.log.training(ds, &r.model, MAIN_SIZE, &conditions);
            }
        }
    }
    let mut probe = None;
    for o in &outcomes {
        if o.selected() && o.entry.variant.is_sol() {
            rec.log.selected(ds, o.entry.variant, o.entry.size);
        }
        for r in &o.runs {
            save_and_record(ctx, ds, o, r, rec)?;
            if o.selected() && probe.is_none() {
                probe = Some((r.model.trained.model.params.clone(), o.entry.size));
            }
        }
    }
    if !ctx.validation_only {
        rec.log
            .held_out_readings
            .insert(ds, splits.held_out().readings());
    }
    Ok(probe)
}

/// Every variant at the main size and, for the capacity sweep, `non` and the
/// first SOL at the other sizes; every training seed. The largest first, so
/// that the workers finish together.
fn plan(options: &Options, seeds: &common::Seeds) -> Plan<Variant, NetSize> {
    let sol = options.unrolls().first().copied().map(Variant::Sol);
    let mut plan: Vec<(Variant, NetSize)> = Vec::new();
    let mut sweep = options.capacity.clone();
    sweep.sort_by_key(|s| std::cmp::Reverse(s.width * s.width * (2 * s.blocks + 2)));
    let (larger, smaller): (Vec<NetSize>, Vec<NetSize>) = sweep
        .iter()
        .partition(|s| s.width * s.width * (2 * s.blocks + 2) > 16 * 16 * 6);
    for size in larger {
        for variant in [Some(Variant::Non), sol].into_iter().flatten() {
            plan.push((variant, size));
        }
    }
    for &variant in options.variants.iter().filter(|v| **v != Variant::Src) {
        plan.push((variant, MAIN_SIZE));
    }
    for size in smaller {
        for variant in [Some(Variant::Non), sol].into_iter().flatten() {
            plan.push((variant, size));
        }
    }
    Plan::new(plan, seeds.train.iter().map(|&s| TrainSeed(s)).collect())
}

/// The held-out runs of `models` (parameters, size, seed) at every held-out
/// Re: each model at each Re is one job, and the workers share them.
fn held_out_runs(
    ctx: &Ctx,
    models: &[(Option<&Params<f64>>, NetSize, u64)],
    refs: &[Reference],
    bar: &(dyn Progress + Sync),
) -> Result<Vec<HeldOutRun>, BoxError> {
    let jobs: Vec<(usize, usize)> = (0..models.len())
        .flat_map(|m| (0..refs.len()).map(move |r| (m, r)))
        .collect();
    let runs = run_jobs(&jobs, ctx.threads, |&(m, r)| {
        let (params, size, seed) = models[m];
        let (net, _) = ctx.new_net(size, seed)?;
        let h = Hybrid::new(ctx.coarse.clone(), net);
        let run = study::held_out_re(&h, params, &refs[r], &ctx.sizes)?;
        bar.inc(1);
        Ok::<_, BoxError>(run)
    })?;
    let mut runs = runs.into_iter();
    Ok((0..models.len())
        .map(|_| HeldOutRun {
            per_re: runs.by_ref().take(refs.len()).collect(),
        })
        .collect())
}

/// The baselines' held-out readings: `src` (the uncorrected coarse solver)
/// and the reference's last state (for the charts).
fn baselines(
    ctx: &Ctx,
    splits: &Splits<Vec<Reference>>,
    bar: &(dyn Progress + Sync),
) -> Result<(HeldOutRun, FlowState<f64>), BoxError> {
    let invalid = |e: BoxError| diffphys::learn::LearnError::Invalid {
        what: "held-out",
        message: e.to_string(),
    };
    let src = splits
        .held_out()
        .evaluate_baseline(|refs| {
            held_out_runs(ctx, &[(None, MAIN_SIZE, 0)], refs, bar).map_err(invalid)
        })?
        .remove(0);
    let last = splits
        .held_out()
        .evaluate_baseline(|refs| Ok(refs[0].states[ctx.sizes.long].clone()))?;
    Ok((src, last))
}

/// What a trained model leaves: its saved model (with the settings and
/// figures that describe it) and, when the held-out split was read, the
/// capacity sweep's entry and the report's.
fn save_and_record(
    ctx: &Ctx,
    ds: u64,
    o: &learn_study::Outcome<Variant, NetSize, Model, Option<HeldOutRun>>,
    r: &learn_study::Run<Model, Option<HeldOutRun>>,
    rec: &mut Record,
) -> Result<(), BoxError> {
    let Ctx { options, sizes, .. } = ctx;
    let m = &r.model;
    let t = &m.trained.model;
    let mut card = model::card(sizes, m.job.size, ctx.arithmetic)
        .provenance("variant", m.job.variant.name())
        .provenance("chosen_on_validation", o.chosen)
        .provenance("data_seed", ds)
        .provenance("train_seed", m.job.seed.0)
        .provenance("learning_rate", m.job.lr)
        .provenance("corrector_evaluations", m.job.evaluations)
        .provenance("kept_iteration", t.best_iteration)
        .provenance("validation", t.validation)
        .provenance("train_re", &options.train_re)
        .provenance("validation_re", &options.validation_re);
    if let Some(run) = &r.held_out {
        card = card.provenance("held_out_per_re", model::per_re_json(run));
    }
    let name = model::dir_name(&m.job.variant.name(), m.job.size, ds, m.job.seed.0);
    SavedModel::save(ctx.args.out.join("models").join(name), &t.params, &card)?;
    let Some(run) = &r.held_out else {
        return Ok(());
    };
    let first_sol = options.unrolls().first().copied().map(Variant::Sol);
    let family = match m.job.variant {
        Variant::Non => Some("non"),
        v if Some(v) == first_sol => Some("sol"),
        _ => None,
    };
    if let Some(variant) = family {
        rec.capacity.add(SweepRun {
            size: m.job.size.label(),
            params: t.params.count(),
            variant: variant.into(),
            seed: m.job.seed.0,
            figures: vec![run.mean(), run.long_mean()],
        });
    }
    if m.job.size == MAIN_SIZE {
        rec.results
            .record(&m.job.variant.name(), ds, Some(m.job.seed.0), run)?;
    }
    if o.selected() {
        rec.results
            .record("sol_selected", ds, Some(m.job.seed.0), run)?;
    }
    Ok(())
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
        let speed_on = |refs: &[Reference]| study::speed(&hybrid, params, refs, sizes);
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
