//! What every example shares: its command line (`--small` for CI, `--out DIR` for
//! charts, `--npy`), parsed by clap with [`parse_args`], and the closing JSON line.

#![allow(dead_code)] // each example uses a different part

use std::ffi::OsString;
use std::path::PathBuf;

use clap::error::ErrorKind;
use clap::{Command, Parser};

/// The exit code of a usage error: `EX_USAGE` of BSD's `sysexits.h`.
pub const EX_USAGE: i32 = 64;

/// The id of [`ExampleArgs::out`], whose default [`parse_args`] sets per example.
const OUT: &str = "example_out";

/// The options every example takes, flattened into its own `clap::Parser`.
#[derive(Debug, Clone, clap::Args)]
pub struct ExampleArgs {
    /// Run at a small size (CI and quick checks).
    #[arg(long)]
    pub small: bool,
    /// Folder for charts and other files, created if missing.
    // `parse_args` replaces this default with `out/NAME`.
    #[arg(long, id = OUT, value_name = "DIR", default_value = "out")]
    pub out: PathBuf,
    /// Write the fields and gradients as `.npy` files under `OUT/npy`.
    #[arg(long)]
    pub npy: bool,
}

/// Parses the command line into `C`, the example `name`'s flags beside the
/// flattened [`ExampleArgs`], whose `--out` defaults to `out/NAME`; creates that
/// folder.
///
/// `--help` and `--version` print and exit 0; any other clap error prints
/// clap's message (an unknown flag with the list of valid ones) and exits
/// [`EX_USAGE`].
///
/// # Errors
/// When the `--out` folder cannot be created.
pub fn parse_args<C: Parser>(name: &'static str) -> Result<C, String> {
    parse_args_with(name, |c| c)
}

/// [`parse_args`] with the command edited first (for help text that only
/// the scene knows, such as its defaults).
///
/// # Errors
/// As [`parse_args`].
pub fn parse_args_with<C: Parser>(
    name: &'static str,
    edit: impl FnOnce(Command) -> Command,
) -> Result<C, String> {
    let argv: Vec<OsString> = std::env::args_os().collect();
    let mut command = edit(command::<C>(name));
    let mut matches = command
        .try_get_matches_from_mut(&argv)
        .unwrap_or_else(|e| exit_on(&e, &command, &argv));
    if let Some(out) = matches.get_one::<PathBuf>(OUT) {
        std::fs::create_dir_all(out)
            .map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    }
    Ok(C::from_arg_matches_mut(&mut matches).unwrap_or_else(|e| exit_on(&e, &command, &argv)))
}

/// [`parse_args`] of `argv` (its first item the program), with the error
/// returned instead of printed, and no folder created.
pub fn try_parse_args_from<C: Parser>(
    name: &'static str,
    argv: impl IntoIterator<Item = impl Into<OsString> + Clone>,
) -> Result<C, clap::Error> {
    let mut matches = command::<C>(name).try_get_matches_from(argv)?;
    C::from_arg_matches_mut(&mut matches)
}

/// `C`'s command, named `name`, with `--out` (where `C` has [`ExampleArgs`])
/// defaulting to `out/NAME`.
fn command<C: Parser>(name: &'static str) -> Command {
    let command = C::command().name(name);
    if command.get_arguments().any(|a| a.get_id() == OUT) {
        // clap (without its `string` feature) keeps `&'static str`s; a
        // process parses its command line once.
        let out: &'static str = format!("out/{name}").leak();
        command.mut_arg(OUT, |a| a.default_value(out))
    } else {
        command
    }
}

/// Prints `error` and exits: 0 after `--help` or `--version`, else
/// [`EX_USAGE`], after an unknown flag with the flags of the (sub)command
/// `argv` names.
fn exit_on(error: &clap::Error, command: &Command, argv: &[OsString]) -> ! {
    // printing to a closed pipe is no reason to panic
    let _ = error.print();
    if !error.use_stderr() {
        std::process::exit(0);
    }
    if error.kind() == ErrorKind::UnknownArgument {
        eprintln!("\nvalid flags: {}", valid_flags(command, argv));
    }
    std::process::exit(EX_USAGE)
}

/// The long flags (and subcommands) of `command`, or of the subcommand `argv`
/// names.
fn valid_flags(command: &Command, argv: &[OsString]) -> String {
    let command = argv.iter().skip(1).fold(command, |c, arg| {
        arg.to_str().and_then(|a| c.find_subcommand(a)).unwrap_or(c)
    });
    let flags = command
        .get_arguments()
        .filter(|a| !a.is_hide_set())
        .filter_map(|a| a.get_long().map(|long| format!("--{long}")));
    let subcommands = command.get_subcommands().map(|s| s.get_name().to_owned());
    flags.chain(subcommands).collect::<Vec<_>>().join(", ")
}

impl ExampleArgs {
    /// With `--npy`, writes each `(name, array, meaning)` as `OUT/npy/{name}.npy`
    /// and an `index.json` naming them; without it, nothing.
    pub fn write_npy(
        &self,
        arrays: &[(&str, ndarray::ArrayViewD<'_, f64>, &str)],
    ) -> Result<(), diffphys::report::ReportError> {
        if !self.npy {
            return Ok(());
        }
        let mut npy = diffphys::report::npy::NpyWriter::new(self.out.join("npy"))?;
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

/// The learning scenes' seeds, flattened beside [`ExampleArgs`] (whose
/// `--small` sets their defaults).
#[derive(Debug, Clone, clap::Args)]
pub struct Seeds {
    /// Data seeds, each a fresh draw of the train, validation and held-out
    /// splits (1 with --small).
    #[arg(
        long = "data-seeds",
        visible_alias = "data-seed",
        value_name = "LIST",
        value_delimiter = ',',
        default_value = "1,2,3",
        default_value_if("small", "true", "1")
    )]
    pub data: Vec<u64>,
    /// Training seeds, each a network initialisation and sampling stream
    /// (1 with --small).
    #[arg(
        long = "train-seeds",
        value_name = "LIST",
        value_delimiter = ',',
        default_value = "1,2,3",
        default_value_if("small", "true", "1")
    )]
    pub train: Vec<u64>,
}

pub use diffphys::report::peak_rss_bytes;
