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
                    reference(cache, sizes, &coarse.scene, fine, (&base, bump), re, &tick)
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
        validation_report,
        validation_per_re,
        sigma_used,
        pinned_face_error,
        ..
    } = rec;
    let new_net = |size, seed| ctx.new_net(size, seed);
    let train: Vec<Trajectory> = splits
        .train
        .iter()
        .map(|r| window(r, 0, r.states.len()))
        .collect();
    let validation: Vec<Trajectory> = splits
        .validation
        .iter()
        .flat_map(|r| [0].into_iter().map(|s| window(r, s, sizes.rollout + 1)))
        .collect();
    let sigma = one_step_rms(coarse, &train)?;
    // What no corrector can remove: the pinned faces' error (train and
    // validation Re; the body decides it, see `Body`).
    let free = free_faces(&coarse.scene);
    let mut pinned = Vec::new();
    for (re, t) in options
        .train_re
        .iter()
        .zip(&train)
        .chain(options.validation_re.iter().zip(&validation))
    {
        pinned.push((*re, study::pinned_face_error(coarse, &free, t)?));
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
    validation_report.add("src", ds, None, src_val);
    let src_per_re = per_trajectory(&hybrid, None, &validation, sizes.rollout)?;
    for (re, e) in options.validation_re.iter().zip(&src_per_re) {
        validation_per_re
            .entry("src".into())
            .or_default()
            .entry(re.to_string())
            .or_default()
            .push(*e);
    }
    println!("  noise sigma (one-step RMS error of the coarse solver) {sigma:.2e}; src validation {src_val:.4} (per Re {src_per_re:.4?})");

    mem("src");
    Ok((train, validation, sigma))
}

/// Phases 2 and 3 of data seed `ds`: the learning rates on validation, then
/// every entry of the plan at every training seed; the groups at the main size
/// and those of the capacity sweep.
pub(crate) fn train_variants(
    ctx: &Ctx,
    ds: u64,
    (train, validation): (&[Trajectory], &[Trajectory]),
    sigma: f64,
    rec: &mut Record,
) -> Result<(Groups, Groups), BoxError> {
    let Ctx {
        options,
        seeds,
        args,
        coarse,
        ..
    } = ctx;
    let (threads, arithmetic, evaluations) = (ctx.threads, ctx.arithmetic, ctx.evaluations);
    let Record {
        validation_report,
        chosen_lr,
        train_seconds,
        validation_curves,
        validation_per_re,
        ..
    } = rec;
    let sizes = &ctx.sizes;
    let setup = Setup {
        schedule: LrSchedule::Cosine {
            final_fraction: 0.1,
        },
        validation_steps: sizes.rollout,
        validation_evaluations: args.pick(VALIDATION_EVALUATIONS, 32),
        coarse,
        arithmetic,
        sigma,
        data_seed: ds,
        train,
        validation,
    };
    let run = |jobs: &[Job]| {
        run_jobs(jobs, threads, |job| {
            train_one(&setup, job).map_err(|e| e.to_string())
        })
    };
    let lr_of = learning_rates(ctx, ds, &run, chosen_lr)?;
    let lr_for = |v: Variant| {
        match v {
            Variant::Sol(_) => lr_of.get("sol"),
            _ => lr_of.get("non"),
        }
        .copied()
        .unwrap_or(options.learning_rates[0])
    };

    // Phase 3: every variant at the main size and, for the capacity
    // sweep, non and the first SOL at the other sizes; every training seed.
    // The largest first, so the workers finish together.
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
    let plan = Plan::new(plan, seeds.train.iter().map(|&s| TrainSeed(s)).collect());
    let jobs: Vec<Job> = plan
        .jobs()
        .into_iter()
        .map(|j| Job {
            variant: j.variant,
            size: j.size,
            seed: j.seed.0,
            lr: lr_for(j.variant),
            evaluations,
        })
        .collect();
    let mut groups: Vec<(Variant, Vec<Model>)> = Vec::new();
    let mut capacity_groups: Vec<(Variant, Vec<Model>)> = Vec::new();
    for Group {
        variant,
        size,
        runs: group,
        ..
    } in plan.groups(run(&jobs)?)?
    {
        for m in &group {
            let key = if size == MAIN_SIZE {
                validation_report.add(
                    &variant.name(),
                    ds,
                    Some(m.seed),
                    m.trained.model.validation,
                );
                for (re, e) in options.validation_re.iter().zip(&m.validation_per_re) {
                    validation_per_re
                        .entry(variant.name())
                        .or_default()
                        .entry(re.to_string())
                        .or_default()
                        .push(*e);
                }
                variant.name()
            } else {
                format!("{}_{}", variant.name(), size.label())
            };
            let t = &m.trained.model;
            validation_curves.insert(
                format!("{key}_data_{ds}_seed_{}", m.seed),
                json!({"curve": t.validation_curve, "kept_iteration": t.best_iteration,
                       "failures": t.validation_failures}),
            );
            train_seconds.entry(key).or_default().push(m.seconds);
        }
        if size == MAIN_SIZE {
            groups.push((variant, group));
        } else {
            capacity_groups.push((variant, group));
        }
    }

    mem("training");
    Ok((groups, capacity_groups))
}

/// Trains a list of jobs on the workers (the first error, as text).
type Trainings<'a> = dyn Fn(&[Job]) -> std::result::Result<Vec<Model>, String> + 'a;

/// Phase 2: the learning rate of `non` (and `noise`) and of SOL, on
/// validation: pilot runs at a quarter of the budget, first training seed
/// (`run` trains a list of jobs); every pilot's score goes to `chosen_lr`.
fn learning_rates(
    ctx: &Ctx,
    ds: u64,
    run: &Trainings<'_>,
    chosen_lr: &mut serde_json::Map<String, Value>,
) -> Result<BTreeMap<&'static str, f64>, BoxError> {
    let (options, seeds, evaluations) = (&ctx.options, &ctx.seeds, ctx.evaluations);
    let families: Vec<(&'static str, Variant)> = [
        ("non", Variant::Non),
        (
            "sol",
            Variant::Sol(options.unrolls().first().copied().unwrap_or(4)),
        ),
    ]
    .into_iter()
    .filter(|(f, _)| {
        if *f == "non" {
            options
                .variants
                .iter()
                .any(|v| matches!(v, Variant::Non | Variant::Noise))
        } else {
            !options.unrolls().is_empty()
        }
    })
    .collect();
    let pilots = pilot_learning_rates(&families, &options.learning_rates, |pilots| {
        let first_seed = seeds.train[0];
        let jobs: Vec<Job> = pilots
            .iter()
            .map(|&((_, variant), lr)| Job {
                variant,
                size: MAIN_SIZE,
                seed: first_seed,
                lr,
                evaluations: evaluations.div_ceil(PILOT_DIVISOR),
            })
            .collect();
        Ok::<_, BoxError>(
            run(&jobs)?
                .iter()
                .map(|m| m.trained.model.validation)
                .collect(),
        )
    })?;
    let lr_of: BTreeMap<&str, f64> = pilots.chosen.iter().map(|&((f, _), lr)| (f, lr)).collect();
    for ((family, _), scores) in &pilots.scores {
        let best = lr_of[family];
        println!("  learning rate for {family}: {best:.0e} (pilot validation {scores:?})");
        chosen_lr.insert(
            format!("{family}_pilots_data_{ds}"),
            json!(scores
                .iter()
                .map(|(lr, v)| json!({"lr": lr, "validation": v}))
                .collect::<Vec<_>>()),
        );
    }
    for (f, lr) in &lr_of {
        chosen_lr.insert(format!("{f}_data_{ds}"), json!(lr));
    }
    Ok(lr_of)
}

/// Phases 4 and 5 of data seed `ds`: selection on validation, then the
/// held-out split, each trained model once (and saved); the selected SOL
/// corrector's parameters for the speed study.
pub(crate) fn select_and_evaluate(
    ctx: &Ctx,
    ds: u64,
    splits: &Splits<Vec<Reference>>,
    (groups, capacity_groups): (Groups, Groups),
    rec: &mut Record,
) -> Result<Option<Probe>, BoxError> {
    let Ctx {
        options,
        sizes,
        args,
        coarse,
        ..
    } = ctx;
    let (threads, arithmetic) = (ctx.threads, ctx.arithmetic);
    let Record {
        results,
        selected_k,
        selected_size,
        capacity_runs,
        held_out_readings,
        ..
    } = rec;
    let new_net = |size, seed| ctx.new_net(size, seed);
    // Phase 4: selection on validation only. Every SOL variant trained,
    // at every size, is a candidate: the unroll and the corrector's size
    // are both chosen here; the others are candidates on their own.
    let labelled = groups
        .into_iter()
        .chain(capacity_groups)
        .map(|(variant, g): (Variant, Vec<Model>)| {
            let size = g.first().map_or(MAIN_SIZE, |m| m.size);
            (Entry { variant, size }, g)
        })
        .collect();
    let selections = select_groups(
        labelled,
        |e| matches!(e.variant, Variant::Sol(_)),
        |m| m.trained.model.validation,
    )?;
    if let Some(Entry {
        variant: Variant::Sol(k),
        size,
    }) = selections.first().map(|s| *s.chosen_label())
    {
        let size = size.label();
        println!("  selected by validation: sol_{k} at {size}");
        selected_k.insert(ds.to_string(), json!(k));
        selected_size.insert(ds.to_string(), json!(size));
    }

    // Phase 5: held-out, each trained model once.
    let bar = progress_bar(
        options.held_out_re.len() * (1 + selections.iter().map(|s| s.models.len()).sum::<usize>()),
        &format!("data {ds}: held-out"),
    );
    let invalid = |e: BoxError| diffphys::learn::LearnError::Invalid {
        what: "held-out",
        message: e.to_string(),
    };
    // Each model at each held-out Re is one job; the workers share them.
    let evaluate = |models: &[(Option<&Params<f64>>, NetSize, u64)], refs: &[Reference]| {
        let jobs: Vec<(usize, usize)> = (0..models.len())
            .flat_map(|m| (0..refs.len()).map(move |r| (m, r)))
            .collect();
        let runs = run_jobs(&jobs, threads, |&(m, r)| {
            let (params, size, seed) = models[m];
            let (net, _) = new_net(size, seed).map_err(|e| e.to_string())?;
            let h = Hybrid::new(coarse.clone(), net);
            let run = study::held_out_re(&h, params, &refs[r], sizes).map_err(|e| e.to_string());
            bar.inc(1);
            run
        })?;
        let mut runs = runs.into_iter();
        Ok::<_, BoxError>(
            (0..models.len())
                .map(|_| HeldOutRun {
                    per_re: runs.by_ref().take(refs.len()).collect(),
                })
                .collect::<Vec<_>>(),
        )
    };
    let src = splits
        .held_out()
        .evaluate_baseline(|refs| evaluate(&[(None, MAIN_SIZE, 0)], refs).map_err(invalid))?
        .remove(0);
    results.record("src", ds, None, &src);
    let reference_last = splits
        .held_out()
        .evaluate_baseline(|refs| Ok(refs[0].states[sizes.long].clone()))?;
    results
        .last
        .entry("reference".into())
        .or_insert(reference_last);
    let mut probe: Option<(Params<f64>, NetSize)> = None;
    for selection in selections {
        for model in selection.models {
            let e = splits.held_out().evaluate(model, |group, refs| {
                let models: Vec<_> = group
                    .iter()
                    .map(|m| (Some(&m.trained.model.params), m.size, m.seed))
                    .collect();
                evaluate(&models, refs).map_err(invalid)
            })?;
            for (run, m) in e.result.iter().zip(&e.model) {
                let t = &m.trained.model;
                let card = model::card(sizes, m.size, arithmetic)
                    .provenance("variant", m.variant.name())
                    .provenance("chosen_on_validation", e.chosen)
                    .provenance("data_seed", ds)
                    .provenance("train_seed", m.seed)
                    .provenance("learning_rate", m.lr)
                    .provenance("corrector_evaluations", m.evaluations)
                    .provenance("kept_iteration", t.best_iteration)
                    .provenance("validation", t.validation)
                    .provenance("train_re", &options.train_re)
                    .provenance("validation_re", &options.validation_re)
                    .provenance("held_out_per_re", model::per_re_json(run));
                let name = model::dir_name(&m.variant.name(), m.size, ds, m.seed);
                SavedModel::save(args.out.join("models").join(name), &t.params, &card)?;
                let params = t.params.count();
                if m.size != MAIN_SIZE || matches!(m.variant, Variant::Non | Variant::Sol(_)) {
                    let first_sol = options.unrolls().first().copied();
                    let in_sweep =
                        m.variant == Variant::Non || Some(m.variant) == first_sol.map(Variant::Sol);
                    if in_sweep {
                        capacity_runs.push((
                            m.size,
                            m.variant,
                            m.seed,
                            run.mean(),
                            run.long_mean(),
                            params,
                        ));
                    }
                }
                if m.size == MAIN_SIZE {
                    results.record(&m.variant.name(), ds, Some(m.seed), run);
                }
                if matches!(m.variant, Variant::Sol(_)) && e.chosen {
                    results.record("sol_selected", ds, Some(m.seed), run);
                    if probe.is_none() {
                        probe = Some((m.trained.model.params.clone(), m.size));
                    }
                }
            }
        }
    }
    bar.finish_and_clear();
    mem("held-out");
    let (models_read, baseline_reads) = splits.held_out().readings();
    held_out_readings.insert(
        format!("data_{ds}"),
        json!({"trained_models": models_read, "baseline_readings": baseline_reads}),
    );
    Ok(probe)
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
        let result = splits.held_out().evaluate_baseline(|refs| {
            study::speed(&hybrid, params, refs, sizes, &coarse.scene).map_err(|e| {
                diffphys::learn::LearnError::Invalid {
                    what: "speed",
                    message: e.to_string(),
                }
            })
        })?;
        speed = result;
        let (models_read, baseline_reads) = splits.held_out().readings();
        rec.held_out_readings.insert(
            format!("data_{}", splits.seed.0),
            json!({"trained_models": models_read, "baseline_readings": baseline_reads}),
        );
        mem("speed");
        pressure = study::pressure_solves(sizes, options.validation_re[0])?;
    }

    Ok((speed, pressure))
}
