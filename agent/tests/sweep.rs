//! Sweeps that survive and spread: shard folders merged by `agent sweep --report` give
//! the unsharded sweep's points, front and summary; a sweep killed with SIGKILL in the
//! middle of a job finishes with `--resume` (after its folder was moved), keeping the
//! finished jobs, continuing the killed one from its checkpoint and starting over a run
//! without one; bad `--shard` and `--report` input is refused naming the flag, file or
//! job. Runs the real CLI binary against a real env_server.
//!
//! A job resumed from a checkpoint matches the uninterrupted run only up to its actors'
//! first env step after the resume (env sessions cannot be saved, see resume.rs), so the
//! resumed sweep's point of that job is compared by its budget, not its returns.

mod cli;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::checkpoint::run::latest_checkpoint;
use cli::{agent_cmd, copy_dir, run_dir_in, smoke_dst};

/// Three settings, one seed, 2500 env steps each (about 2 s a job on 2 cores), a
/// checkpoint every 50 learner steps so that a kill finds one. One job at a time
/// (`population = 1`): the kill below comes between jobs, after job 0 finished.
fn tiny_sweep(dir: &Path) -> PathBuf {
    let (_, base) = smoke_dst(dir);
    let text = std::fs::read_to_string(&base)
        .unwrap()
        .replace("checkpoint_period = 100", "checkpoint_period = 50");
    std::fs::write(&base, text).unwrap();
    let path = dir.join("sweep.toml");
    std::fs::write(
        &path,
        r#"
name = "tiny"
base = "dst.toml"
total_env_steps = 2500
population = 1
reference_point = { time = -25.0, treasure = 0.0 }
[grid]
kind = "epsilon"
product = { time = [0.01], treasure = [0.01, 0.1, 1.0] }
"#,
    )
    .unwrap();
    path
}

/// `agent sweep <args> --server <server>`, which must succeed.
fn sweep(server: &str, args: &[&str]) {
    let out = agent_cmd(&["sweep"])
        .args(args)
        .args(["--server", server])
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "agent sweep {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `agent <args>`'s stderr, which must fail.
fn refused(args: &[&str]) -> String {
    let out = agent_cmd(args).stderr(Stdio::piped()).output().unwrap();
    assert!(!out.status.success(), "agent {args:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A CSV's rows without its last column (`run_dir`, which names the folders, whose
/// names carry their start times).
fn rows(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| l.rsplit_once(',').unwrap().0.to_string())
        .collect()
}

/// `summary.json` without its wall-clock and folder fields.
fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    let mut s: serde_json::Value = serde_json::from_str(&text).unwrap();
    let map = s.as_object_mut().unwrap();
    map.remove("wall_seconds");
    map.remove("dir");
    for p in map["points"].as_array_mut().unwrap() {
        p.as_object_mut().unwrap().remove("run_dir");
    }
    s
}

/// The run folder of job `job` in the sweep folder `dir` (a job has at most one).
fn job_run(dir: &Path, job: usize) -> Option<PathBuf> {
    run_dir_in(&dir.join("runs").join(format!("{job:03}")))
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shards_merge_into_the_unsharded_front_and_a_killed_sweep_resumes() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let address = server.address();
    let tmp = tempfile::tempdir().unwrap();
    let config = tiny_sweep(tmp.path());
    let dir = |name: &str| tmp.path().join(name);

    // The unsharded sweep, its two shards, and their merge.
    sweep(
        address,
        &["--config", s(&config), "--dir", s(&dir("whole"))],
    );
    for i in 0..2 {
        let shard = format!("{i}/2");
        let out = dir(&format!("shard{i}"));
        sweep(
            address,
            &["--config", s(&config), "--shard", &shard, "--dir", s(&out)],
        );
    }
    let status = agent_cmd(&["sweep", "--report", s(&dir("shard0")), s(&dir("shard1"))])
        .args(["--dir", s(&dir("merged"))])
        .status()
        .unwrap();
    assert!(status.success());
    // Shard 0 holds jobs 0 and 2, shard 1 job 1, each under its index.
    assert!(job_run(&dir("shard0"), 2).is_some() && job_run(&dir("shard0"), 1).is_none());
    assert!(job_run(&dir("shard1"), 1).is_some());
    for file in ["points.csv", "front.csv"] {
        assert_eq!(
            rows(&dir("merged").join(file)),
            rows(&dir("whole").join(file)),
            "{file}"
        );
    }
    assert_eq!(summary(&dir("merged")), summary(&dir("whole")));
    for file in ["front.png", "front.svg"] {
        assert!(dir("merged").join(file).exists(), "{file}");
    }

    // Folders that do not make one sweep are refused, naming the file or the job.
    let e = refused(&["sweep", "--report", s(&dir("shard0")), s(&dir("whole"))]);
    assert!(
        e.contains("job 0 (time=0.01 treasure=0.01, seed 0) is in both"),
        "{e}"
    );
    sweep(
        address,
        &[
            "--config",
            s(&config),
            "--shard",
            "2/3",
            "--dir",
            s(&dir("third")),
        ],
    );
    let e = refused(&["sweep", "--report", s(&dir("shard1")), s(&dir("third"))]);
    assert!(
        e.contains("missing job 0 (time=0.01 treasure=0.01, seed 0)"),
        "{e}"
    );
    for (file, from, to) in [
        ("sweep.toml", "-25.0", "-30.0"),
        ("base.toml", "batch_size = 64", "batch_size = 32"),
    ] {
        let edited = dir(&format!("edited-{file}"));
        copy_dir(&dir("shard1"), &edited);
        let text = std::fs::read_to_string(edited.join(file)).unwrap();
        assert!(text.contains(from), "{file}: {text}");
        std::fs::write(edited.join(file), text.replace(from, to)).unwrap();
        let e = refused(&["sweep", "--report", s(&dir("shard0")), s(&edited)]);
        let expected = format!(
            "{}: expected the same as {}, got a different one",
            edited.join(file).display(),
            dir("shard0").join(file).display()
        );
        assert!(e.contains(&expected), "{e}");
    }
    let unfinished = dir("unfinished");
    copy_dir(&dir("shard1"), &unfinished);
    std::fs::remove_file(job_run(&unfinished, 1).unwrap().join("summary.json")).unwrap();
    let e = refused(&["sweep", "--report", s(&dir("shard0")), s(&unfinished)]);
    assert!(
        e.contains("job 1 (time=0.01 treasure=0.1, seed 0) has not finished"),
        "{e}"
    );

    // Kill -9 the unsharded sweep once job 0 has finished and job 1 has a checkpoint.
    let killed = dir("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_agent"))
        .args([
            "sweep",
            "--config",
            s(&config),
            "--dir",
            s(&killed),
            "--server",
            address,
        ])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    let run1 = loop {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "no checkpoint of job 1 in 60 s"
        );
        if let Some(run) = job_run(&killed, 1)
            && latest_checkpoint(&run).is_ok()
            && !run.join("summary.json").exists()
        {
            break run;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let run0 = job_run(&killed, 0).unwrap();
    let finished = std::fs::read(run0.join("summary.json")).unwrap();
    let (_, at_kill) = latest_checkpoint(&run1).unwrap();
    assert!(at_kill.env_steps < 2500, "{}", at_kill.env_steps);

    // Job 2 as a kill before its first checkpoint leaves it: a run folder with a config
    // only. (The kill may have come before job 2 started, or just after.)
    let abandoned = match job_run(&killed, 2) {
        Some(run) if latest_checkpoint(&run).is_err() => run,
        Some(run) => panic!("job 2 has a checkpoint already: {}", run.display()),
        None => {
            let run = killed.join("runs/002/dst__mompo__0__19700101-000000");
            std::fs::create_dir_all(&run).unwrap();
            std::fs::copy(run1.join("config.toml"), run.join("config.toml")).unwrap();
            run
        }
    };
    // The folder moves (another mount, say): a sweep folder needs only itself.
    let moved = dir("moved");
    std::fs::rename(&killed, &moved).unwrap();
    let (killed, run0, run1, abandoned) = (
        moved.clone(),
        moved.join(run0.strip_prefix(&killed).unwrap()),
        moved.join(run1.strip_prefix(&killed).unwrap()),
        moved.join(abandoned.strip_prefix(&killed).unwrap()),
    );
    sweep(address, &["--resume", s(&killed)]);
    // Job 0 is kept as it was, job 1 continues in its folder to the budget, job 2 runs.
    assert_eq!(job_run(&killed, 0).unwrap(), run0);
    assert_eq!(std::fs::read(run0.join("summary.json")).unwrap(), finished);
    assert_eq!(job_run(&killed, 1).unwrap(), run1);
    assert!(
        !abandoned.exists(),
        "job 2's run without a checkpoint starts over"
    );
    assert!(job_run(&killed, 2).is_some());
    let env_steps = |run: PathBuf| {
        let text = std::fs::read_to_string(run.join("summary.json")).unwrap();
        serde_json::from_str::<serde_json::Value>(&text).unwrap()["env_steps"].as_u64()
    };
    assert_eq!(
        env_steps(run1),
        env_steps(job_run(&dir("whole"), 1).unwrap())
    );
    let (whole, resumed) = (
        rows(&dir("whole").join("points.csv")),
        rows(&killed.join("points.csv")),
    );
    assert_eq!(resumed.len(), 4, "header and three jobs: {resumed:?}");
    for i in [0, 1, 3] {
        // The header, job 0 (finished before the kill) and job 2 (started after it)
        // are the uninterrupted sweep's.
        assert_eq!(resumed[i], whole[i], "row {i}");
    }
    server.stop().await.unwrap();
}

#[test]
fn bad_shards_and_report_folders_are_refused_naming_the_flag_or_file() {
    let tmp = tempfile::tempdir().unwrap();
    let config = tiny_sweep(tmp.path());
    for (shard, why) in [("3/2", "\"3/2\""), ("x", "\"x\"")] {
        let e = refused(&["sweep", "--config", s(&config), "--shard", shard]);
        assert!(
            e.contains(&format!("invalid value '{shard}' for '--shard <I/N>'"))
                && e.contains("expected I/N with whole numbers 0 <= I < N")
                && e.contains(why),
            "{e}"
        );
    }
    let e = refused(&["sweep", "--config", s(&config), "--shard", "0/4"]);
    assert!(
        e.contains("--shard: expected N at most 3 (the sweep has 3 jobs), got N = 4"),
        "{e}"
    );
    let e = refused(&["sweep", "--report", s(tmp.path())]);
    assert!(
        e.contains(&format!(
            "{}: expected a sweep folder (agent sweep writes sweep.json there)",
            tmp.path().display()
        )),
        "{e}"
    );
    let e = refused(&["sweep", "--resume", s(tmp.path())]);
    assert!(e.contains("expected a sweep folder"), "{e}");
}
