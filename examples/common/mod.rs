//! What every example shares: its command line (`--small` for CI, `--out DIR` for
//! charts) and the closing JSON line.

#![allow(dead_code)] // each example uses a different part

use std::path::PathBuf;

/// The options every example takes.
#[derive(Debug, Clone)]
pub struct ExampleArgs {
    /// Run at a small size (CI and quick checks).
    pub small: bool,
    /// Folder for charts and other files.
    pub out: PathBuf,
    /// Overrides the number of optimisation iterations.
    pub iterations: Option<usize>,
    /// Write the fields and gradients as `.npy` files under `OUT/npy`.
    pub npy: bool,
}

impl ExampleArgs {
    /// Reads `--small`, `--out DIR` and `--iterations N` from the command line;
    /// `default_out` names the folder under `out/` when `--out` is not given.
    pub fn parse(default_out: &str) -> Result<Self, String> {
        Self::parse_from(default_out, std::env::args().skip(1))
    }

    /// [`ExampleArgs::parse`] of the arguments `it` (an example that takes
    /// options of its own removes them first).
    pub fn parse_from(
        default_out: &str,
        mut it: impl Iterator<Item = String>,
    ) -> Result<Self, String> {
        let mut args = ExampleArgs {
            small: false,
            out: PathBuf::from("out").join(default_out),
            iterations: None,
            npy: false,
        };
        while let Some(arg) = it.next() {
            match arg.as_str() {
                "--small" => args.small = true,
                "--npy" => args.npy = true,
                "--out" => args.out = it.next().ok_or("--out needs a folder")?.into(),
                "--iterations" => {
                    let n = it.next().ok_or("--iterations needs a number")?;
                    args.iterations = Some(
                        n.parse()
                            .map_err(|_| format!("--iterations: not a number: {n}"))?,
                    );
                }
                "-h" | "--help" => {
                    println!(
                        "options: --small (CI size), --out DIR (charts), --iterations N, \
                         --npy (fields and gradients as .npy files under DIR/npy)"
                    );
                    std::process::exit(0);
                }
                other => return Err(format!("unknown argument {other:?}; try --help")),
            }
        }
        std::fs::create_dir_all(&args.out)
            .map_err(|e| format!("cannot create {}: {e}", args.out.display()))?;
        Ok(args)
    }

    /// With `--npy`, writes each `(name, array, meaning)` as `OUT/npy/{name}.npy`
    /// and an `index.json` naming them; without it, nothing.
    pub fn write_npy(
        &self,
        arrays: &[(&str, ndarray::ArrayViewD<'_, f64>, &str)],
    ) -> Result<(), diffphys_compare::CompareError> {
        if !self.npy {
            return Ok(());
        }
        let mut npy = diffphys_compare::npy::NpyWriter::new(self.out.join("npy"))?;
        for (name, array, meaning) in arrays {
            npy.write(name, array.view(), meaning)?;
        }
        println!("wrote {}", npy.finish()?.display());
        Ok(())
    }

    /// `small` if running small, else `full`.
    pub fn pick<T>(&self, full: T, small: T) -> T {
        if self.small {
            small
        } else {
            full
        }
    }
}

/// Prints the example's key figures as its last stdout line, with the process's
/// peak resident memory as `peak_rss_bytes` (added where the example did not set
/// it; `null` where the kernel does not say).
pub fn print_json_line(value: &serde_json::Value) {
    let mut value = value.clone();
    if let Some(map) = value.as_object_mut() {
        map.entry("peak_rss_bytes")
            .or_insert_with(|| serde_json::json!(peak_rss_bytes()));
    }
    println!(
        "{}",
        serde_json::to_string(&value).expect("a JSON value serialises")
    );
}

/// The learning scenes' seeds: `--data-seed N` (or `--data-seeds a,b,c`) and
/// `--train-seeds a,b,c`, removed from `args`; the defaults are `full` (or
/// `small` with `--small`).
#[derive(Debug, Clone)]
pub struct Seeds {
    /// Each a fresh draw of the train, validation and held-out splits.
    pub data: Vec<u64>,
    /// Each a network initialisation and sampling stream.
    pub train: Vec<u64>,
}

impl Seeds {
    /// Parses and removes the seed options from `args`.
    pub fn take(args: &mut Vec<String>, small: bool) -> Result<Self, String> {
        let list = |v: &str, what: &str| -> Result<Vec<u64>, String> {
            let seeds: Vec<u64> = v
                .split(',')
                .map(|s| {
                    s.trim()
                        .parse()
                        .map_err(|_| format!("{what}: not a seed list: {v}"))
                })
                .collect::<Result<_, _>>()?;
            if seeds.is_empty() {
                return Err(format!("{what}: no seeds"));
            }
            Ok(seeds)
        };
        let mut seeds = if small {
            Seeds {
                data: vec![1],
                train: vec![1],
            }
        } else {
            Seeds {
                data: vec![1, 2, 3],
                train: vec![1, 2, 3],
            }
        };
        let mut i = 0;
        while i < args.len() {
            let what = args[i].clone();
            if ["--data-seed", "--data-seeds", "--train-seeds"].contains(&what.as_str()) {
                let value = args
                    .get(i + 1)
                    .ok_or(format!("{what} needs a value"))?
                    .clone();
                match what.as_str() {
                    "--train-seeds" => seeds.train = list(&value, &what)?,
                    _ => seeds.data = list(&value, &what)?,
                }
                args.drain(i..i + 2);
            } else {
                i += 1;
            }
        }
        Ok(seeds)
    }
}

/// The command line with the learning scenes' seed options taken out.
pub fn parse_with_seeds(default_out: &str) -> Result<(ExampleArgs, Seeds), String> {
    let mut raw: Vec<String> = std::env::args().skip(1).collect();
    let small = raw.iter().any(|a| a == "--small");
    let seeds = Seeds::take(&mut raw, small)?;
    Ok((
        ExampleArgs::parse_from(default_out, raw.into_iter())?,
        seeds,
    ))
}

/// The process's peak resident set size in bytes (`VmHWM` of
/// `/proc/self/status`; `None` where there is no such file).
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
