//! The example plug-in (`examples/plugin`) trained by the agent, as its guide tells a
//! user to: a real server finds `reach-energy` through the entry point the package's
//! `pyproject.toml` declares, and `examples/plugin/mompo.toml` trains on it.
//!
//! Installing the package into the shared venv would register it for every other
//! test's server, so the test lays out what `pip install` would put on `sys.path`: a
//! dist-info whose `entry_points.txt` comes from the pyproject's own table, beside the
//! package's source folder, both on the server's `PYTHONPATH`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train};

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/plugin")
}

/// A folder on which the example is installed as pip would leave it; returns the
/// `PYTHONPATH` that shows it to a server (ahead of this process's own `PYTHONPATH`,
/// which may name the env_server checkout under test).
fn install(root: &Path) -> String {
    let text = std::fs::read_to_string(example().join("pyproject.toml")).unwrap();
    let pyproject: toml::Table = text.parse().unwrap();
    let project = pyproject["project"].as_table().unwrap();
    let (name, version) = (
        project["name"].as_str().unwrap(),
        project["version"].as_str().unwrap(),
    );
    let info = root.join(format!("{}-{version}.dist-info", name.replace('-', "_")));
    std::fs::create_dir_all(&info).unwrap();
    std::fs::write(
        info.join("METADATA"),
        format!("Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"),
    )
    .unwrap();
    let points = project["entry-points"]["env_server.envs"]
        .as_table()
        .unwrap();
    let lines: String = points
        .iter()
        .map(|(id, target)| format!("{id} = {}\n", target.as_str().unwrap()))
        .collect();
    std::fs::write(
        info.join("entry_points.txt"),
        format!("[env_server.envs]\n{lines}"),
    )
    .unwrap();
    let mut path = format!("{}:{}", root.display(), example().join("src").display());
    if let Some(inherited) = std::env::var_os("PYTHONPATH").filter(|p| !p.is_empty()) {
        path = format!("{path}:{}", inherited.to_string_lossy());
    }
    path
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_example_plugin_trains_with_its_run_config() {
    let site = tempfile::tempdir().unwrap();
    let server = LocalServer::start(&ServerOptions {
        environment: BTreeMap::from([("PYTHONPATH".into(), install(site.path()))]),
        ..ServerOptions::default()
    })
    .await
    .unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut cfg = TrainConfig::load_with(
        &example().join("mompo.toml"),
        &[
            "run.total_env_steps=600".into(),
            "run.min_replay_transitions=200".into(),
            "run.log_period=20".into(),
            "run.eval_episodes=2".into(),
        ],
    )
    .expect("the example's run config loads");
    cfg.run.runs_dir = runs.path().to_path_buf();
    let s = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .expect("the example trains");
    assert_eq!(
        s.objectives,
        vec!["reach".to_string(), "energy".to_string()]
    );
    assert!(s.env_steps >= 600, "env steps {}", s.env_steps);
    assert!(s.learner_steps > 100, "learner steps {}", s.learner_steps);
    // 600 env steps (both instances together) hold 12 episodes of 50 steps.
    assert!(s.episodes >= 10, "episodes {}", s.episodes);
    assert_eq!(s.eval_return.len(), 2);
    // Each objective's per-step reward lies in [-1.8, 0] (reach) and [-1, 0] (energy),
    // so a 50-step return lies in [-90, 0] and [-50, 0].
    let bounds = [-90.0, -50.0];
    for (r, lo) in s.eval_return.iter().zip(bounds) {
        assert!(
            (lo..=0.0).contains(r),
            "evaluation return {r} outside [{lo}, 0]"
        );
    }
    server.stop().await.unwrap();
}

/// Issue 27's silent mistake, now refused: the pendulum preset's `source =
/// "action_norm"` left on the example's `energy` objective (which is -a^2, and declares
/// no closed form) stops `train` before it builds a learner or a run directory, with an
/// error that names the field and the env's declaration.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_closed_form_the_env_does_not_declare_is_refused_before_training() {
    let site = tempfile::tempdir().unwrap();
    let server = LocalServer::start(&ServerOptions {
        environment: BTreeMap::from([("PYTHONPATH".into(), install(site.path()))]),
        ..ServerOptions::default()
    })
    .await
    .unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut cfg = TrainConfig::load_with(
        &example().join("mompo.toml"),
        &["learner.objectives.1.source=\"action_norm\"".into()],
    )
    .expect("the example's run config loads");
    assert_eq!(cfg.learner.objectives[1].name, "energy");
    cfg.run.runs_dir = runs.path().to_path_buf();
    let err = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .expect_err("energy declares no closed form");
    assert_eq!(
        err.to_string(),
        r#"learner.objectives.1.source: source = "action_norm" computes objective "energy" in closed form, which needs the env to declare closed_form = action_norm for it; the env declares closed_form = none (use source = "learned")"#
    );
    assert_eq!(
        std::fs::read_dir(runs.path()).unwrap().count(),
        0,
        "no run directory"
    );
    server.stop().await.unwrap();
}
