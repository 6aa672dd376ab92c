//! A malformed `--server` is refused when the command line is read, by every command
//! that takes one, naming the flag and quoting the value (not the config field
//! `env.servers` it would replace), before any server is started or config read.

mod cli;

use cli::agent_cmd;
use std::process::Stdio;

#[test]
fn every_command_names_the_server_flag_for_a_bad_address() {
    let bad = "dns:envs.example.org"; // no port
    let commands: [&[&str]; 5] = [
        &["train", "--config", "missing.toml"],
        &["sweep", "--config", "missing.toml"],
        &["eval", "--checkpoint", "missing"],
        &["envs"],
        &["demo"],
    ];
    for args in commands {
        let out = agent_cmd(args)
            .args(["--server", bad])
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(
            stderr.contains("'--server <ADDRESS>'")
                && stderr.contains(bad)
                && stderr.contains("expected dns:NAME:PORT"),
            "{args:?}: {stderr}"
        );
    }
}
