//! The report of `wake_flow`: the held-out figures gathered over every run,
//! the floors, the charts and the closing JSON line. Declared by the example
//! itself (not by the scene module, which the tests include).

use super::*;

/// The tables, charts, `--npy` arrays and the JSON line.
pub(crate) fn report(
    ctx: &Ctx,
    rec: Record,
    (speed, pressure): (Value, Value),
    params_count: serde_json::Map<String, Value>,
    run_start: Instant,
) -> Result<(), BoxError> {
    let sizes = &ctx.wake.sizes;
    let Ctx {
        options,
        seeds,
        args,
        coarse,
        fine,
        ..
    } = ctx;
    let (arithmetic, evaluations) = (ctx.arithmetic, ctx.evaluations);
    println!(
        "\nheld-out figures over {} steps, long rollout {} steps (data seeds {:?} x train seeds {:?}):",
        sizes.rollout, sizes.long, seeds.data, seeds.train
    );
    rec.print_tables();
    let (floors, capacity) = floors(options, &rec);
    let sol = !options.unrolls().is_empty();
    rec.charts(
        &args.out,
        coarse.scene(),
        (CHANNEL.centre, 0.5 * CHANNEL.diameter),
        sol,
    )?;
    let npy: Vec<(String, ndarray::ArrayViewD<'_, f64>)> = (rec.results.last)
        .iter()
        .flat_map(|(name, s)| {
            [
                (format!("last_{name}_ux"), s.ux.view().into_dyn()),
                (format!("last_{name}_uy"), s.uy.view().into_dyn()),
            ]
        })
        .collect();
    args.write_npy(
        &npy.iter()
            .map(|(n, a)| {
                (
                    n.as_str(),
                    a.view(),
                    "velocity component (u_x [nx + 1, ny] or u_y [nx, ny + 1]) after the long rollout at the first held-out Re",
                )
            })
            .collect::<Vec<_>>(),
    )?;
    println!("floors: {floors}");
    let training_iterations: serde_json::Map<String, Value> = options
        .variants
        .iter()
        .filter(|v| **v != Variant::Src)
        .map(|&v| (v.name(), json!(v.adam_steps(evaluations, STEP_EVALUATIONS))))
        .collect();
    let held_split: (Vec<f64>, Vec<f64>) = options
        .held_out_re
        .iter()
        .partition(|&&r| options.inside(r));
    // How the body and the reference were made, and the error they leave on
    // the pinned faces (a key of its own: the line's macro is deep already).
    let setup_json = json!({
        "body": sizes.body.label(),
        "reference_scheme": sizes.reference.label(),
        "coarse_advection": wake::name_in(&wake::ADVECTIONS, sizes.advection),
        "coarse_splitting": wake::name_in(&wake::SPLITTINGS, sizes.splitting),
        "network_arithmetic": wake::name_in(&wake::ARITHMETICS, arithmetic),
        "pinned_face_error": rec.pinned_face_error,
    });
    let mut line = json!({
        "example": "wake_flow",
        "small": args.small,
        "grid_coarse": [sizes.ny, sizes.nx],
        "grid_reference": [fine.grid().ny, fine.grid().nx],
        "dt_coarse": sizes.dt,
        "dt_reference": fine.dt(),
        "skipped_transient_steps": {"base": sizes.warm_base, "per_re": sizes.warm, "base_re": sizes.base_re},
        "recorded_steps": sizes.record,
        "rollout_steps": sizes.rollout,
        "rollout_starts": sizes.starts,
        "long_rollout_steps": sizes.long,
        "re_definition": "U D / nu, U = 1 inflow speed, D = 0.2 cylinder diameter",
        "re_range": CHANNEL.re_range,
        "data_seeds": seeds.data,
        "train_seeds": seeds.train,
        "train_re": options.train_re,
        "validation_re": options.validation_re,
        "held_out_re": {"inside": held_split.0, "outside": held_split.1},
        "training_iterations": training_iterations,
        "corrector_evaluations_per_training": evaluations,
        "setup": setup_json,
        "params": params_count,
        "main_size": MAIN_SIZE.label(),
        "capacity": capacity,
        "speed": speed,
        "pressure": pressure,
        "floors_met": floors,
        "peak_rss_bytes": common::peak_rss_bytes(),
        "wall_s": run_start.elapsed().as_secs_f64(),
    });
    for (key, value) in rec.to_json() {
        line[key] = value;
    }
    // `--validation-only`: trained and selected, the held-out split unread
    // (every held-out figure is absent, the speed study ran on validation).
    line["validation_only"] = json!(ctx.validation_only);
    line["saved_models"] = json!(args.out.join("models").display().to_string());
    // The floors are the full scene's (docs/11): `--small`'s budgets and grids
    // measure that the study runs, not what it reaches.
    line["floors_apply"] = json!(!args.small);
    if args.small {
        println!("floors: not applied at --small (they are the full scene's)");
    }
    if ctx.validation_only {
        println!("validation only: the held-out split was not read (no held-out figure, no floor measured; the speed study ran on validation)");
    }
    common::print_json_line(&line);
    let missed = diffphys::learn::missed_floors(&line["floors_met"]);
    if !args.small && !missed.is_empty() {
        return Err(format!("a floor of the scene is not met: {}", missed.join(", ")).into());
    }
    Ok(())
}

/// The floors of the scene (docs/11) from the held-out figures, and the
/// capacity sweep's JSON.
fn floors(options: &Options, rec: &Record) -> (Value, Value) {
    let capacity_runs = &rec.capacity;
    let sol_src = rec.ratio_per_re("sol_selected", "src");
    let floor_sol_src = if sol_src.values().any(Option::is_none) || sol_src.is_empty() {
        json!("not measured")
    } else {
        json!(sol_src.values().all(|r| r.unwrap_or(f64::INFINITY) <= 0.3))
    };
    let sol = options.unrolls().first().map(|&k| Variant::Sol(k).name());
    let mut capacity = capacity_runs.to_json(&["sol", "non"]);
    capacity["variant_sol"] = json!(sol);
    let smallest = |k| capacity_runs.ratio(&SIZES[0].label(), "sol", "non", k);
    let (smallest, smallest_long) = (smallest(0), smallest(1));
    let floor_small = match smallest {
        Some(r) => json!(r <= 0.8),
        None => json!("not measured"),
    };
    let floors = json!({
        "sol_selected_at_most_0.3x_src_every_held_out_re": floor_sol_src,
        "sol_selected_over_src_per_re": sol_src,
        "goal_sol_selected_at_most_0.1x_src": if sol_src.is_empty() || sol_src.values().any(Option::is_none) { json!("not measured") } else { json!(sol_src.values().all(|r| r.unwrap_or(f64::INFINITY) <= 0.1)) },
        "smallest_size_sol_at_most_0.8x_non_100_steps": floor_small,
        "smallest_size_sol_over_non_100_steps": smallest,
        "smallest_size_sol_over_non_long": smallest_long,
        "peak_rss_under_2_gib": common::peak_rss_bytes().map(|b| b < 2 << 30),
    });
    (floors, capacity)
}
