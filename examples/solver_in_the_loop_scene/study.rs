//! The measurements of `solver_in_the_loop` beyond training: checkpointing a
//! long unroll (peak heap, time, the gradient against the full tape) and the
//! charts.

use std::collections::BTreeMap;
use std::path::Path;
use std::rc::Rc;
use std::time::Instant;

use diffphys::learn::{states_at, Corrector, Hybrid, Schedule, Simulator, Trajectory};
use diffphys::nn::Params;
use diffphys::report::chart::{line_chart_svg, LineChart, Series};

use super::BoxError;

/// One schedule's gradient of a long unroll.
#[derive(Debug, Clone)]
pub struct CheckpointRun {
    pub label: String,
    pub peak_bytes: usize,
    pub seconds: f64,
    pub gradient: Vec<f64>,
}

/// The gradient of the unrolled loss over the whole of `probe` under every
/// schedule, each the faster of two runs; `reset` and `heap` read the counting
/// allocator (`(current, peak)` bytes).
pub fn checkpointing<S: Simulator + 'static, C: Corrector + 'static>(
    hybrid: &Hybrid<S, C>,
    params: &Params<f64>,
    probe: &[Trajectory],
    reset: &dyn Fn(),
    heap: &dyn Fn() -> (usize, usize),
) -> Result<Vec<CheckpointRun>, BoxError> {
    let long = probe[0].len() - 1;
    let targets = Rc::new(
        (1..=long)
            .map(|t| Ok(states_at(probe, t)?.fields))
            .collect::<Result<Vec<_>, diffphys::learn::LearnError>>()?,
    );
    let s0 = states_at(probe, 0)?;
    let mut schedules = vec![(Schedule::Full, "full tape".to_string())];
    schedules.extend([8, 16, 32, 64, 128].map(|m| (Schedule::Every(m), format!("every {m}"))));
    schedules.extend([2, 4, 8].map(|b| {
        (
            Schedule::Nested { branches: b },
            format!("nested, {b} branches"),
        )
    }));
    let mut runs: Vec<CheckpointRun> = Vec::new();
    for (schedule, label) in schedules {
        let mut best: Option<CheckpointRun> = None;
        for _ in 0..2 {
            reset();
            let (before, start) = (heap().0, Instant::now());
            let gradient = hybrid.unrolled_gradient(params, &s0, Rc::clone(&targets), schedule)?;
            let seconds = start.elapsed().as_secs_f64();
            let peak_bytes = heap().1.saturating_sub(before);
            if best.as_ref().is_none_or(|b| seconds < b.seconds) {
                best = Some(CheckpointRun {
                    label: label.clone(),
                    peak_bytes,
                    seconds,
                    gradient,
                });
            }
        }
        runs.push(best.expect("two runs"));
    }
    let full = runs[0].clone();
    println!("\ncheckpointing {long} steps ({} states):", probe.len());
    println!("| schedule | peak heap (MB) | time (s) | heap / full | time / full | max abs gradient diff |");
    println!("|---|---|---|---|---|---|");
    for r in &runs {
        println!(
            "| {} | {:.2} | {:.3} | {:.4} | {:.2} | {:.1e} |",
            r.label,
            r.peak_bytes as f64 / 1e6,
            r.seconds,
            r.peak_bytes as f64 / full.peak_bytes as f64,
            r.seconds / full.seconds,
            max_abs_diff(&r.gradient, &full.gradient)
        );
    }
    Ok(runs)
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The largest gradient difference to the full tape over all schedules, and the
/// heap and time ratios of a checkpoint every `segment` steps.
pub fn summary(runs: &[CheckpointRun], segment: usize) -> Result<(f64, f64, f64), BoxError> {
    let full = &runs[0];
    let worst = runs
        .iter()
        .map(|r| max_abs_diff(&r.gradient, &full.gradient))
        .fold(0.0, f64::max);
    let headline = runs
        .iter()
        .find(|r| r.label == format!("every {segment}"))
        .ok_or("headline schedule missing")?;
    Ok((
        worst,
        headline.peak_bytes as f64 / full.peak_bytes as f64,
        headline.seconds / full.seconds,
    ))
}

/// `relative_error.svg` (the mean per-step curve of every method) and
/// `checkpoint_memory_time.svg`.
pub fn charts(
    out: &Path,
    curves: &BTreeMap<String, Vec<Vec<f64>>>,
    runs: &[CheckpointRun],
) -> Result<(), BoxError> {
    let series: Vec<Series> = curves
        .iter()
        .map(|(name, c)| Series::mean_per_step(name.clone(), c))
        .collect();
    line_chart_svg(
        &out.join("relative_error.svg"),
        &LineChart {
            title: "Held-out rollouts: relative error (mean over data seeds × training seeds)",
            x_label: "step",
            y_label: "‖u − u_ref‖ / ‖u_ref‖",
            log_x: false,
            log_y: true,
            series: &series,
        },
    )?;
    let points = runs
        .iter()
        .map(|r| (r.seconds, r.peak_bytes as f64 / 1e6))
        .collect();
    line_chart_svg(
        &out.join("checkpoint_memory_time.svg"),
        &LineChart {
            title: "Checkpointing: peak heap against time of one gradient (full, every m, nested)",
            x_label: "time of forward + backward (s)",
            y_label: "peak heap (MB)",
            log_x: false,
            log_y: true,
            series: &[Series::new("schedules", points)],
        },
    )?;
    println!("charts written to {}", out.display());
    Ok(())
}
