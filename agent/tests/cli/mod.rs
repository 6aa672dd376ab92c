//! Running the real `agent` binary in tests: the command, a smoke config writing its
//! runs under a temporary directory, finding the run directory it made, and reading
//! its files back.
#![allow(dead_code, unreachable_pub, reason = "each test file uses a subset")]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use agent::env::server_process::default_python;
use agent::runtime::learner::LearnerRecord;

/// `agent <args>`, quiet.
pub fn agent_cmd(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_agent"));
    c.args(args)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    c
}

/// The first run directory under `runs`, once there is one.
pub fn run_dir_in(runs: &Path) -> Option<PathBuf> {
    std::fs::read_dir(runs)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .find(|p| p.is_dir())
}

/// `configs/smoke/dst.toml` writing its runs under `dir/runs`: (runs dir, config path).
pub fn smoke_dst(dir: &Path) -> (PathBuf, PathBuf) {
    let runs = dir.join("runs");
    let smoke = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst.toml");
    let text = std::fs::read_to_string(smoke)
        .unwrap()
        .replace("[run]\n", &format!("[run]\nruns_dir = {runs:?}\n"));
    let config = dir.join("dst.toml");
    std::fs::write(&config, text).unwrap();
    (runs, config)
}

/// learner.jsonl's `learner_step` column.
pub fn learner_steps(run: &Path) -> Vec<u64> {
    learner_rows(run)
        .iter()
        .map(|r| r["learner_step"].as_u64().unwrap())
        .collect()
}

/// learner.jsonl without its wall-clock columns.
pub fn learner_rows(run: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(run.join("learner.jsonl")).unwrap();
    text.lines()
        .map(|l| {
            let mut row: serde_json::Value = serde_json::from_str(l).unwrap();
            let map = row.as_object_mut().unwrap();
            for clock in LearnerRecord::CLOCK_FIELDS {
                map.remove(clock);
            }
            row
        })
        .collect()
}

/// episodes.csv's rows without the wall-clock column.
pub fn episode_rows(run: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(run.join("episodes.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| l.rsplit_once(',').unwrap().0.to_string())
        .collect()
}

/// summary.json.
pub fn summary(run: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap()
}

/// Copies the folder `from` to `to`, recursively.
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).unwrap();
        }
    }
}

/// The JSON that `agent/tests/<script>` prints when run with `args` by the venv's
/// Python; its stderr in the message when it fails.
pub fn python_json<S: AsRef<std::ffi::OsStr>>(script: &str, args: &[S]) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join(script);
    let out = succeeds(Command::new(default_python()).arg(script).args(args));
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Runs `command` to its end and returns its output; its stderr in the message when it
/// fails.
pub fn succeeds(command: &mut Command) -> Output {
    let out = command.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// The run's scalars as TensorBoard reads them (agent/tests/read_tensorboard.py).
pub fn tensorboard_scalars(run: &Path) -> BTreeMap<String, Vec<(u64, f64)>> {
    serde_json::from_value(python_json("read_tensorboard.py", &[run])).unwrap()
}
