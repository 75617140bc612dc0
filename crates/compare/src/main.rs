//! `diffphys-compare`: naive vs implicit gradients through conjugate gradient,
//! measured in one run (time, tape and heap memory, accuracy against an exact
//! solve), written to a folder as `results.json`, `report.md` and SVG charts.
//!
//! ```text
//! cargo run --release -p diffphys-compare                       # the default study
//! cargo run --release -p diffphys-compare -- --quick --out tmp  # seconds, for CI
//! cargo run --release -p diffphys-compare -- --sizes 64,128 --rtol 1e-6,1e-10 --precision f64
//! cargo run --release -p diffphys-compare -- --sizes 64,128,256,512,1024,2048 --rtol 1e-8 \
//!     --precision f64 --operators laplacian --methods exact,implicit,implicit_mgpcg
//! cargo run --release -p diffphys-compare -- stability          # where methods fail
//! cargo run --release -p diffphys-compare -- stability --quick  # seconds, for CI
//! ```
//!
//! Every timed method runs under one policy (`--warmup`, `--repeat`,
//! `--statistic`; by default one untimed warm-up run, then the best of 3), stated
//! in the output and in the closing line. Stdout ends with one JSON line of key
//! figures (counts, per-method summaries, floors, the timing policy, output
//! folder), with `"ok": false` and the `error` when the run failed.
//!
//! Exit status: 0 when runs completed; 64 for invalid arguments; 1 for an
//! error, and for a sweep that measured nothing: no run completed (every one
//! refused or failed; the closing line says why, e.g. the memory guard's
//! estimate and limit), or runs failed and no floor was measured (a floor
//! without a measurement is "not measured", never held). The results are
//! written in every case.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand};
use diffphys_compare::alloc::CountingAllocator;
use diffphys_compare::cli::progress_bar;
use diffphys_compare::format::format_bytes;
use diffphys_compare::harness::{
    cg_speedup, compute_floors, prepare_out_dir, run_sweep, run_sweep_npy, write_charts, Statistic,
    SweepConfig, FLOOR_N,
};
use diffphys_compare::memory::MemoryBudget;
use diffphys_compare::model::{Floor, Method, Precision, ResultRow, RunStatus, Verdict};
use diffphys_compare::npy::NpyWriter;
use diffphys_compare::problem::OperatorKind;
use diffphys_compare::progress::{LineProgress, Progress};
use diffphys_compare::report::{
    floors_text, key_figures_value, memory_refusals, method_summary, render_table, write_report_md,
    write_results_json, Report, RunCounts,
};
use diffphys_compare::stability::{
    converged_rtol, render_stability_md, result_rows, run_stability, stability_key_figures,
    unroll_table, write_stability_charts, write_stability_json, StabilityConfig, Study,
};
use diffphys_compare::{CompareError, Result};

#[global_allocator]
static HEAP: CountingAllocator = CountingAllocator::new();

/// Naive vs implicit gradients through a Poisson solve: time, memory, accuracy.
#[derive(Debug, Parser)]
#[command(name = "diffphys-compare", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    sweep: SweepArgs,
    /// Threads of the parallel kernels (0: one per core) [default: one per core,
    /// or RAYON_NUM_THREADS]. Results do not depend on it.
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Arrays of at least this many elements are split across threads [default:
    /// 262144, or DIFFPHYS_PARALLEL_MIN_LEN]. Results do not depend on it.
    #[arg(long, global = true)]
    parallel_min_len: Option<usize>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Where methods fail: precision, iterations past convergence, unconverged
    /// solves, conditioning, initial guesses, long unrolls. Writes
    /// stability.json, stability.md and SVG charts.
    Stability {
        /// Output folder.
        #[arg(long, default_value = "out/stability")]
        out: PathBuf,
        /// Small grids and short sweeps that finish in seconds, for CI.
        #[arg(long)]
        quick: bool,
    },
}

/// The sweep of the default command. Each list flag replaces its default; giving
/// only one of `--iters` and `--rtol` runs only that kind of stopping rule.
#[derive(Debug, Args)]
struct SweepArgs {
    /// Grid sizes n (n × n cells), comma-separated [default: 32,64,128,256].
    #[arg(long, value_delimiter = ',')]
    sizes: Vec<usize>,
    /// Fixed CG iteration counts [default: 10,30,100,300].
    #[arg(long, value_delimiter = ',')]
    iters: Vec<usize>,
    /// Relative CG tolerances [default: 1e-4,1e-6,1e-8].
    #[arg(long, value_delimiter = ',')]
    rtol: Vec<f64>,
    /// Precisions: f32, f64 [default: f32,f64].
    #[arg(long, value_delimiter = ',', value_parser = parse_precision)]
    precision: Vec<Precision>,
    /// Operators: laplacian, aniso<ratio> [default: laplacian,aniso100].
    #[arg(long, value_delimiter = ',', value_parser = parse_operator)]
    operators: Vec<OperatorKind>,
    /// Methods to run, comma-separated [default: all]. `implicit_mgpcg` is the
    /// implicit gradient with multigrid-preconditioned CG solves; exact's
    /// gradient is the error reference whether or not its row is run.
    #[arg(
        long,
        value_delimiter = ',',
        value_parser = PossibleValuesParser::new(Method::SELECTABLE.map(Method::name))
            .try_map(|s| Method::parse(&s))
    )]
    methods: Vec<Method>,
    /// Untimed warm-up runs before the timed runs of every timed method [default: 1].
    #[arg(long)]
    warmup: Option<usize>,
    /// Timed runs of every timed method; the row reports the one --statistic
    /// picks [default: 3; 1 with --quick].
    #[arg(long)]
    repeat: Option<usize>,
    /// Which timed run a row reports: best (fastest) or median [default: best].
    #[arg(long, value_parser = parse_statistic)]
    statistic: Option<Statistic>,
    /// Iteration cap of tolerance runs [default: 20000].
    #[arg(long)]
    max_iters: Option<usize>,
    /// Skip naive runs whose tape would exceed this many MiB [default: 3072].
    #[arg(long)]
    naive_tape_limit_mib: Option<usize>,
    /// Refuse runs whose estimated memory exceeds this many MiB [default: the
    /// memory available, from /proc/meminfo].
    #[arg(long)]
    memory_limit_mib: Option<usize>,
    /// Output folder for results.json, report.md and the charts.
    #[arg(long, default_value = "out/compare")]
    out: PathBuf,
    /// Also write, for the plain Laplacian in f64, each size's b, target, exact
    /// gradient and every method's gradient as .npy files under OUT/npy.
    #[arg(long)]
    npy: bool,
    /// A tiny sweep (sizes 8 and 16) that finishes in seconds, for CI.
    #[arg(long)]
    quick: bool,
}

fn parse_precision(s: &str) -> std::result::Result<Precision, String> {
    Precision::parse(s).map_err(|e| e.to_string())
}

fn parse_statistic(s: &str) -> std::result::Result<Statistic, String> {
    Statistic::parse(s).map_err(|e| e.to_string())
}

fn parse_operator(s: &str) -> std::result::Result<OperatorKind, String> {
    OperatorKind::parse(s).map_err(|e| e.to_string())
}

impl SweepArgs {
    fn config(&self) -> Result<SweepConfig> {
        let mut c = if self.quick {
            SweepConfig::quick()
        } else {
            SweepConfig::default_run()
        };
        if !self.sizes.is_empty() {
            c.sizes = self.sizes.clone();
        }
        match (self.iters.is_empty(), self.rtol.is_empty()) {
            (true, true) => {}
            (false, true) => {
                c.iters = self.iters.clone();
                c.rtols.clear();
            }
            (true, false) => {
                c.iters.clear();
                c.rtols = self.rtol.clone();
            }
            (false, false) => {
                c.iters = self.iters.clone();
                c.rtols = self.rtol.clone();
            }
        }
        if !self.precision.is_empty() {
            c.precisions = self.precision.clone();
        }
        if !self.operators.is_empty() {
            c.operators = self.operators.clone();
        }
        if let Some(m) = self.max_iters {
            c.max_iters = m;
        }
        if let Some(mib) = self.naive_tape_limit_mib {
            c.naive_tape_limit_bytes = mib.saturating_mul(1 << 20);
        }
        c.memory_limit_mib = self.memory_limit_mib;
        if !self.methods.is_empty() {
            // In the sweep's order, each once.
            c.methods = Method::SELECTABLE
                .into_iter()
                .filter(|m| self.methods.contains(m))
                .collect();
        }
        if let Some(w) = self.warmup {
            c.timing.warmup = w;
        }
        if let Some(r) = self.repeat {
            c.timing.repeats = r;
        }
        if let Some(s) = self.statistic {
            c.timing.statistic = s;
        }
        c.validate()?;
        Ok(c)
    }
}

fn describe(config: &SweepConfig, args: &SweepArgs) -> Vec<String> {
    let list = |v: Vec<String>| {
        if v.is_empty() {
            "none".to_string()
        } else {
            v.join(", ")
        }
    };
    vec![
        format!(
            "command: `diffphys-compare {}`",
            std::env::args().skip(1).collect::<Vec<_>>().join(" ")
        ),
        format!("mode: {}", if args.quick { "quick" } else { "full" }),
        format!(
            "grid sizes: {}",
            list(config.sizes.iter().map(|n| format!("{n}²")).collect())
        ),
        format!(
            "fixed iteration counts: {}",
            list(config.iters.iter().map(|k| k.to_string()).collect())
        ),
        format!(
            "tolerances: {} (cap {} iterations)",
            list(config.rtols.iter().map(|r| format!("{r:e}")).collect()),
            config.max_iters
        ),
        format!(
            "precisions: {}",
            list(
                config
                    .precisions
                    .iter()
                    .map(|p| p.name().to_string())
                    .collect()
            )
        ),
        format!(
            "operators: {}",
            list(config.operators.iter().map(|o| o.label()).collect())
        ),
        format!(
            "methods: {}",
            list(
                config
                    .methods
                    .iter()
                    .map(|m| m.name().to_string())
                    .collect()
            )
        ),
        format!("timing: {}", config.timing.describe()),
        format!("loss: {:?}", config.loss),
        format!(
            "naive tape limit: {}",
            format_bytes(config.naive_tape_limit_bytes)
        ),
        {
            let budget = MemoryBudget::new(config.memory_limit_mib);
            format!(
                "memory limit per run: {} ({})",
                format_bytes(budget.limit_bytes),
                budget.source
            )
        },
        format!(
            "machine: {} logical CPUs, {} {}",
            std::thread::available_parallelism().map_or(0, |n| n.get()),
            std::env::consts::OS,
            std::env::consts::ARCH
        ),
    ]
}

/// A bar on a terminal; elsewhere, one line per run on stderr, except in
/// `--quick` runs (CI logs stay short).
fn sweep_progress(quick: bool) -> Box<dyn Progress> {
    use std::io::IsTerminal;
    if std::io::stderr().is_terminal() || quick {
        Box::new(progress_bar(0, "sweep"))
    } else {
        Box::new(LineProgress::default())
    }
}

/// Why a sweep measured nothing, if it did: no run completed (with the memory
/// guard's reason if it refused runs), or runs failed and no floor was
/// measured. `None` for a sweep with something to show.
fn nothing_measured(rows: &[ResultRow], floors: &[Floor], results: &Path) -> Option<CompareError> {
    let counts = RunCounts::of(rows);
    let first_failure = || {
        rows.iter()
            .find(|r| r.status == RunStatus::Failed)
            .and_then(|r| r.error.as_deref())
            .map(|e| format!("; first failure: {e}"))
            .unwrap_or_default()
    };
    let refusals = || {
        memory_refusals(rows)
            .map(|r| format!("; the memory guard refused runs: {r}"))
            .unwrap_or_default()
    };
    if counts.ok == 0 {
        return Some(CompareError::NothingRan(format!(
            "{}{}{}; see {}",
            counts.describe(),
            refusals(),
            first_failure(),
            results.display()
        )));
    }
    let measured = floors.iter().any(|f| f.verdict() != Verdict::NotMeasured);
    (counts.failed > 0 && !measured).then(|| {
        CompareError::NothingMeasured(format!(
            "no floor was measured (floors are judged at {FLOOR_N}², f64, laplacian, rtol 1e-8, \
             MG-PCG at 64²..2048²) and {} of {} runs failed{}{}; see {}",
            counts.failed,
            counts.runs,
            first_failure(),
            refusals(),
            results.display()
        ))
    })
}

/// What a mode ends with: its closing JSON object and, for a run that completed
/// but measured nothing, why (the exit status is then 1).
type Ending = (serde_json::Value, Option<CompareError>);

fn run(args: &SweepArgs, started: Instant) -> Result<Ending> {
    let config = args.config()?;
    let out = prepare_out_dir(&args.out)?;
    println!("timing: {}", config.timing.describe());
    println!(
        "threads: {}, arrays split across them from {} elements",
        diffphys_tape::parallel::threads(),
        diffphys_tape::parallel::min_parallel_len()
    );
    let progress = sweep_progress(args.quick);
    let (rows, npy_index) = if args.npy {
        let mut npy = NpyWriter::new(out.join("npy"))?;
        let rows = run_sweep_npy(&config, Some(&HEAP), progress.as_ref(), &mut npy)?;
        (rows, Some(npy.finish()?))
    } else {
        (run_sweep(&config, Some(&HEAP), progress.as_ref())?, None)
    };
    let (timing, timing_note) = cg_speedup(&config);
    // Like the other floors, the speedup is judged at 256²; on smaller grids the
    // fixed costs of a solve call dominate, so the ratio is reported, not judged.
    let speedup = match timing {
        Some(t) if t.n == FLOOR_N => (Some(t.speedup()), timing_note),
        Some(t) => (
            None,
            format!(
                "measured {:.2} at {}² only (the floor is judged at {FLOOR_N}²): {timing_note}",
                t.speedup(),
                t.n
            ),
        ),
        None => (None, timing_note),
    };
    let floors = compute_floors(&rows, Some(speedup));
    let (charts, mut notes) = write_charts(&out, &rows);
    let counts = RunCounts::of(&rows);
    if counts.skipped > 0 {
        notes.push(format!(
            "{} naive runs were skipped because their tape would exceed the limit \
             (raise --naive-tape-limit-mib to run them)",
            counts.skipped
        ));
    }
    if let Some(reason) = memory_refusals(&rows) {
        notes.push(format!(
            "{} runs were refused by the memory guard (--memory-limit-mib): {reason}",
            counts.memory_limit
        ));
    }
    write_results_json(&out.join("results.json"), &rows)?;
    let report = Report {
        title: "diffphys-compare: naive vs implicit gradients through CG",
        configuration: describe(&config, args),
        rows: &rows,
        floors: &floors,
        charts,
        notes: notes.clone(),
    };
    write_report_md(&out.join("report.md"), &report)?;

    println!("{}", render_table(&rows));
    println!("timing: {}", config.timing.describe());
    println!("Performance floors:\n{}", floors_text(&floors));
    for n in &notes {
        println!("note: {n}");
    }
    println!(
        "wrote {}, {} and the charts",
        out.join("results.json").display(),
        out.join("report.md").display()
    );
    if let Some(index) = npy_index {
        println!("wrote {}", index.display());
    }
    let mut tail = key_figures_value(&rows, &floors, &out, started.elapsed().as_secs_f64());
    tail["methods"] = method_summary(&rows);
    tail["timing"] = serde_json::json!({
        "warmup": config.timing.warmup,
        "repeats": config.timing.repeats,
        "statistic": config.timing.statistic,
        "policy": config.timing.describe(),
    });
    tail["threads"] = diffphys_tape::parallel::threads().into();
    tail["parallel_min_len"] = diffphys_tape::parallel::min_parallel_len().into();
    let failure = nothing_measured(&rows, &floors, &out.join("results.json"));
    Ok((tail, failure))
}

fn run_stability_mode(out: &Path, quick: bool, started: Instant) -> Result<Ending> {
    let config = if quick {
        StabilityConfig::quick()
    } else {
        StabilityConfig::full()
    };
    let out = prepare_out_dir(out)?;
    let results = run_stability(&config, &progress_bar(0, "stability"))?;
    let (charts, notes) = write_stability_charts(&out, &results);
    write_stability_json(&out.join("stability.json"), &results)?;
    let configuration = vec![
        format!(
            "command: `diffphys-compare {}`",
            std::env::args().skip(1).collect::<Vec<_>>().join(" ")
        ),
        format!("mode: {}", if quick { "quick" } else { "full" }),
        format!(
            "scenes: −∇² p = b with L = ½‖p − p*‖² (the sweep's scene); a CG run converges at \
             relative residual {:e} (f64) / {:e} (f32)",
            converged_rtol::<f64>(),
            converged_rtol::<f32>()
        ),
        format!("configuration: `{}`", serde_json::to_string(&config)?),
        format!(
            "machine: {} logical CPUs, {} {}",
            std::thread::available_parallelism().map_or(0, |n| n.get()),
            std::env::consts::OS,
            std::env::consts::ARCH
        ),
    ];
    let md = render_stability_md(&results, configuration, charts, notes.clone());
    let md_path = out.join("stability.md");
    std::fs::write(&md_path, md).map_err(|e| CompareError::io(&md_path, e))?;

    for (key, title) in [
        (Study::Iterations, "precision and iteration counts"),
        (
            Study::Unconverged,
            "forward solve stopped before convergence",
        ),
        (Study::Conditioning, "conditioning"),
    ] {
        println!("== {title}\n{}", render_table(&result_rows(&results, key)));
    }
    println!(
        "== long unrolls (upwind advection)\n{}",
        unroll_table(&results.unroll, false)
    );
    println!("Findings:");
    for f in &results.findings {
        println!("- {f}");
    }
    println!("Floors:\n{}", floors_text(&results.floors));
    for n in &notes {
        println!("note: {n}");
    }
    println!(
        "wrote {}, {} and the charts",
        out.join("stability.json").display(),
        md_path.display()
    );
    let tail = stability_key_figures(&results, &out, started.elapsed().as_secs_f64());
    Ok((tail, None))
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => e.exit(), // --help, --version
        Err(e) => {
            let _ = e.print();
            println!(
                "{}",
                serde_json::json!({ "mode": "usage", "ok": false, "error": e.kind().to_string() })
            );
            return ExitCode::from(64);
        }
    };
    if let Some(n) = cli.threads {
        if let Err(e) = diffphys_tape::parallel::set_threads(n) {
            eprintln!("error: --threads {n}: {e}");
            return ExitCode::from(64);
        }
    }
    if let Some(len) = cli.parallel_min_len {
        diffphys_tape::parallel::set_min_parallel_len(len);
    }
    let started = Instant::now();
    let (mode, result) = match &cli.command {
        None => ("sweep", run(&cli.sweep, started)),
        Some(Command::Stability { out, quick }) => {
            ("stability", run_stability_mode(out, *quick, started))
        }
    };
    match result {
        Ok((mut tail, failure)) => {
            tail["mode"] = mode.into();
            tail["ok"] = failure.is_none().into();
            if let Some(e) = &failure {
                eprintln!("error: {e}");
                tail["error"] = e.to_string().into();
            }
            println!("{tail}");
            if failure.is_some() {
                ExitCode::from(1)
            } else {
                ExitCode::SUCCESS
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            let code = match e {
                CompareError::InvalidArgument(_) => 64,
                _ => 1,
            };
            println!(
                "{}",
                serde_json::json!({ "mode": mode, "ok": false, "error": e.to_string() })
            );
            ExitCode::from(code)
        }
    }
}
