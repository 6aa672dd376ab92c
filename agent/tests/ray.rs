//! `python -m env_server.tools.ray` running `agent train` over three env servers on a local Ray
//! cluster, with one server killed mid-run: Ray restarts it, the launcher rewrites the
//! address file, the agent's actor moves to a live server listed there (`--server
//! file:PATH`), and the run still reaches its env and learner step budgets. Runs the real
//! CLI binary under the real launcher (the launcher's own tests are
//! env_server/tests/test_ray.py).

mod cli;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use agent::env::server_process::default_python;
use agent::runtime::checkpoint::run::latest_checkpoint;
use cli::{run_dir_in, smoke_dst};

/// `server <i> up at <address> (pid <pid>, node <id>)` lines of the launcher: (index, pid).
fn servers_up(lines: &[String]) -> Vec<(usize, i32)> {
    lines
        .iter()
        .filter_map(|line| {
            let rest = line.split_once("env_server.tools.ray: server ")?.1;
            let (index, rest) = rest.split_once(' ')?;
            if !rest.starts_with("up at ") {
                return None;
            }
            let pid = rest.split_once("(pid ")?.1.split_once(',')?.0;
            Some((index.parse().ok()?, pid.parse().ok()?))
        })
        .collect()
}

#[test]
fn training_over_ray_servers_survives_a_killed_server() {
    let dir = tempfile::tempdir().unwrap();
    let (runs, config) = smoke_dst(dir.path());
    // Three actors, one per server (round-robin), so that every server carries a session.
    let text = std::fs::read_to_string(&config)
        .unwrap()
        .replace("num_envs = 8\n", "num_envs = 4\nnum_actors = 3\n");
    std::fs::write(&config, text).unwrap();
    let address_file = dir.path().join("servers.txt");

    let started = Instant::now();
    let mut launcher = Command::new(default_python())
        .args([
            "-m",
            "env_server.tools.ray",
            "--num-servers",
            "3",
            "--address-file",
        ])
        .arg(&address_file)
        .args(["--server-args", "--log-level WARNING", "--"])
        .arg(env!("CARGO_BIN_EXE_agent"))
        .args(["train", "--config", config.to_str().unwrap()])
        .env_remove("RAY_ADDRESS") // a local Ray for this test, whatever the caller's shell has
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let lines = Arc::new(Mutex::new(Vec::<String>::new()));
    let reader = {
        let lines = Arc::clone(&lines);
        let stderr = launcher.stderr.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("{line}");
                lines.lock().unwrap().push(line);
            }
        })
    };

    // Kill one server (SIGKILL, as a crash) once the learner has made 100 steps.
    let run = loop {
        assert!(
            started.elapsed() < Duration::from_secs(240),
            "no checkpoint past 100 learner steps within 240 s"
        );
        if let Some(status) = launcher.try_wait().unwrap() {
            panic!("the launcher exited early with {status}");
        }
        if let Some(run) = run_dir_in(&runs)
            && let Ok((_, progress)) = latest_checkpoint(&run)
            && progress.learner_steps >= 100
        {
            break run;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let up = servers_up(&lines.lock().unwrap());
    assert_eq!(up.len(), 3, "{up:?}");
    let (victim, pid) = up[1];
    // SAFETY: kill(2) with a valid signal on the pid the launcher reported for its server.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGKILL) }, 0);
    let killed_at = Instant::now();

    let status = loop {
        assert!(
            started.elapsed() < Duration::from_secs(420),
            "the run did not finish within 420 s"
        );
        if let Some(status) = launcher.try_wait().unwrap() {
            break status;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    reader.join().unwrap();
    let lines = lines.lock().unwrap();
    assert!(status.success(), "launcher: {status}\n{}", lines.join("\n"));
    let back = format!("env_server.tools.ray: server {victim} back at ");
    assert!(
        lines.iter().any(|l| l.contains(&back)),
        "server {victim} did not come back:\n{}",
        lines.join("\n")
    );
    eprintln!(
        "run finished {:.1} s after the kill, {:.1} s in all",
        killed_at.elapsed().as_secs_f64(),
        started.elapsed().as_secs_f64()
    );

    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap();
    assert!(summary["interrupted"].is_null(), "{summary}");
    // Three actors each check the budget before a step of 4 instances: up to 3 x 4 over.
    let env_steps = summary["env_steps"].as_u64().unwrap();
    assert!((8000..8000 + 3 * 4).contains(&env_steps), "{summary}");
    // (env steps - 500 before the first learner step) x 0.25 learner steps per env step.
    let (_, progress) = latest_checkpoint(&run).unwrap();
    assert_eq!(progress.learner_steps, (env_steps - 500) / 4, "{summary}");
    assert_eq!(
        summary["learner_steps"].as_u64(),
        Some(progress.learner_steps)
    );
    // The actor on the killed server went on elsewhere.
    let moved = summary["actor_servers"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["servers"].as_array().unwrap().len() > 1)
        .count();
    assert_eq!(moved, 1, "{summary}");
}
