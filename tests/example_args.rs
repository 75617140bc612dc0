//! The examples' shared command line (`examples/common`): `--out` defaults per
//! example, `--small` sets the seeds' defaults, and an unknown flag is a usage
//! error. The exit codes (0 after `--help`, 64 after a bad flag) are checked by
//! CI on every example's binary.

#[path = "../examples/common/mod.rs"]
mod common;

use std::path::Path;

use clap::error::ErrorKind;
use common::{try_parse_args_from, ExampleArgs, Seeds};

/// A learning example's command line: the shared options, the seeds and a
/// flag of its own whose default follows `--small`.
#[derive(Debug, clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: ExampleArgs,
    #[command(flatten)]
    seeds: Seeds,
    /// Adam steps (20 with --small).
    #[arg(long, default_value_t = 1500, default_value_if("small", "true", "20"))]
    iterations: usize,
}

fn parse(argv: &[&str]) -> Result<Cli, clap::Error> {
    try_parse_args_from("demo", std::iter::once("demo").chain(argv.iter().copied()))
}

#[test]
fn defaults_follow_small() {
    let full = parse(&[]).unwrap();
    assert!(!full.common.small && !full.common.npy);
    assert_eq!(full.common.out, Path::new("out").join("demo"));
    assert_eq!(
        (full.seeds.data, full.seeds.train),
        (vec![1, 2, 3], vec![1, 2, 3])
    );
    assert_eq!(full.iterations, 1500);

    let small = parse(&["--small"]).unwrap();
    assert!(small.common.small);
    assert_eq!((small.seeds.data, small.seeds.train), (vec![1], vec![1]));
    assert_eq!(small.iterations, 20);
}

#[test]
fn given_values_win() {
    let cli = parse(&[
        "--small",
        "--out",
        "/tmp/x",
        "--npy",
        "--data-seed",
        "77",
        "--train-seeds",
        "4,5,6",
        "--iterations",
        "3",
    ])
    .unwrap();
    assert_eq!(cli.common.out, Path::new("/tmp/x"));
    assert!(cli.common.npy);
    assert_eq!((cli.seeds.data, cli.seeds.train), (vec![77], vec![4, 5, 6]));
    assert_eq!(cli.iterations, 3);
    assert_eq!(
        parse(&["--data-seeds", "1,2"]).unwrap().seeds.data,
        vec![1, 2]
    );
}

#[test]
fn help_lists_every_flag_with_its_default() {
    let help = parse(&["--help"]).unwrap_err();
    assert_eq!(help.kind(), ErrorKind::DisplayHelp);
    let text = help.to_string();
    for flag in [
        "--small",
        "--out <DIR>",
        "--npy",
        "--data-seeds <LIST>",
        "--train-seeds <LIST>",
        "--iterations <ITERATIONS>",
        "[default: out/demo]",
        "[default: 1,2,3]",
        "[default: 1500]",
    ] {
        assert!(text.contains(flag), "{flag} missing from\n{text}");
    }
}

#[test]
fn bad_flags_and_values_are_usage_errors() {
    let kind = |argv: &[&str]| parse(argv).unwrap_err().kind();
    assert_eq!(kind(&["--no-such-flag"]), ErrorKind::UnknownArgument);
    assert_eq!(kind(&["--iterations", "many"]), ErrorKind::ValueValidation);
    assert_eq!(kind(&["--train-seeds", "1,x"]), ErrorKind::ValueValidation);
    assert_eq!(kind(&["--out"]), ErrorKind::InvalidValue);
}
