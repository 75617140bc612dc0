//! The binary's exit status and closing line tell a user what a run measured:
//! non-zero when it measured nothing, floors without a measurement "not
//! measured" (never held), and the memory guard's reason on the last line.

use std::process::Command;

/// The binary, as CI runs it.
fn harness() -> Command {
    Command::new(env!("CARGO_BIN_EXE_diffphys-compare"))
}

fn temp_dir(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("diffphys-exit-{name}-{}", std::process::id()))
}

/// Runs `command` and returns its exit code, stdout and the JSON of its last
/// non-empty stdout line.
fn run(command: &mut Command) -> (Option<i32>, String, serde_json::Value) {
    let out = command.output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let last = stdout
        .lines()
        .rfind(|l| !l.trim().is_empty())
        .unwrap_or_else(|| panic!("no stdout: {}", String::from_utf8_lossy(&out.stderr)));
    let tail = serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {last}"));
    (out.status.code(), stdout, tail)
}

#[test]
fn a_sweep_that_measures_no_floor_and_loses_runs_exits_non_zero() {
    // 3² cells: the fixed counts 10..300 exceed the 9 unknowns (typed failed
    // rows), and no floor's scene (256², 64²..2048²) is in the sweep.
    let dir = temp_dir("sizes3");
    let (code, _, tail) = run(harness()
        .args([
            "--sizes",
            "3",
            "--precision",
            "f64",
            "--operators",
            "laplacian",
        ])
        .args(["--repeat", "1", "--warmup", "0", "--out"])
        .arg(&dir));
    assert_eq!(code, Some(1), "{tail}");
    assert_eq!(tail["ok"], false);
    let error = tail["error"].as_str().unwrap();
    assert!(
        error.starts_with("nothing measured: no floor was measured"),
        "{error}"
    );
    assert!(error.contains("grid too small"), "{error}");
    assert!(tail["failed"].as_u64().unwrap() > 0, "{tail}");
    // Not one floor was measured, so none holds and the run does not claim they do.
    let floors = tail["floors"].as_object().unwrap();
    assert!(!floors.is_empty());
    for (key, f) in floors {
        assert!(f["measured"].is_null(), "{key}: {f}");
        assert!(f["holds"].is_null(), "{key}: {f}");
        assert_eq!(f["verdict"], "not_measured", "{key}");
    }
    assert_eq!(tail["floors_hold"], serde_json::Value::Null);
    assert_eq!(
        tail["floors_not_measured"].as_array().unwrap().len(),
        floors.len()
    );
    // The results are written all the same, each row with its status.
    let rows: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(dir.join("results.json")).unwrap()).unwrap();
    assert!(rows
        .iter()
        .any(|r| r["status"] == "failed" && r["error"].is_string()));
    assert!(rows.iter().any(|r| r["status"] == "ok"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_quick_run_succeeds_without_claiming_unmeasured_floors() {
    let dir = temp_dir("quick");
    let (code, _, tail) = run(harness()
        .args(["--quick", "--methods", "exact,implicit", "--out"])
        .arg(&dir));
    assert_eq!(code, Some(0), "{tail}");
    assert_eq!(tail["ok"], true);
    assert_eq!(tail["mode"], "sweep");
    assert_eq!(tail["floors_hold"], serde_json::Value::Null);
    assert_eq!(tail["refused"], 0);
    assert_eq!(tail["refused_reason"], serde_json::Value::Null);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn runs_the_memory_guard_refuses_say_why_on_the_closing_line() {
    // Every run refused: a non-zero exit whose last line carries the estimate
    // and the limit.
    let dir = temp_dir("refused");
    let (code, _, tail) = run(harness()
        .args(["--quick", "--sizes", "100000", "--memory-limit-mib", "64"])
        .arg("--out")
        .arg(&dir));
    assert_eq!(code, Some(1), "{tail}");
    assert_eq!(tail["ok"], false);
    let error = tail["error"].as_str().unwrap();
    assert!(error.starts_with("no run succeeded: "), "{error}");
    for part in [
        "refused by the memory guard",
        "needs about",
        "over the limit of 64.0 MiB",
    ] {
        assert!(error.contains(part), "{part}: {error}");
    }
    assert_eq!(tail["refused"], tail["runs"]);
    assert!(tail["refused_reason"]
        .as_str()
        .unwrap()
        .starts_with("memory limit: "));
    std::fs::remove_dir_all(&dir).unwrap();

    // Some refused, the others run: success, and the last line and a note say
    // what was refused and why.
    let (code, stdout, tail) = run(harness()
        .args(["--quick", "--sizes", "8,100000", "--memory-limit-mib", "64"])
        .args(["--methods", "exact,implicit", "--out"])
        .arg(&dir));
    assert_eq!(code, Some(0), "{tail}");
    assert!(tail["refused"].as_u64().unwrap() > 0, "{tail}");
    let reason = tail["refused_reason"].as_str().unwrap();
    assert!(
        reason.contains("100000×100000") && reason.contains("needs about"),
        "{reason}"
    );
    assert!(
        stdout
            .contains("runs were refused by the memory guard (--memory-limit-mib): memory limit:"),
        "{stdout}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}
