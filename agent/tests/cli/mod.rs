//! Running the real `agent` binary in tests: the command, a smoke config writing its
//! runs under a temporary directory, and finding the run directory it made.
#![allow(dead_code, unreachable_pub, reason = "each test file uses a subset")]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

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
