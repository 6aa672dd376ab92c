//! A trained policy in PyTorch (`env_server.trained_policy`) acts as the agent does:
//! a short run is trained, `agent act` (the real binary) writes its deterministic
//! actions for fixed observations, and `agent/tests/python_policy.py` loads the same
//! checkpoint in PyTorch and compares its actions (within 1e-5), then evaluates it
//! through RemoteEnv with `agent eval`'s seeds and instances, which must give the
//! episode returns `agent eval` (the real binary) writes to its `--json` report. On
//! DST (categorical) and pendulum (Gaussian, tanh mean, Box bounds [-2, 2]); and A.3's
//! mocap torso (encoder and latent) on an untrained learner's checkpoint, actions only;
//! and an ε-conditioned pendulum policy at a preference off its training grid, its
//! features carried to every layer (`network.policy_preference = "every_layer"`, and
//! `critic_preference` for the critics it trains with). On the trained Gaussian runs,
//! `scripts/probe_critic.py`'s transcription of the Q critics must also give the
//! agent's Q (`Learner::q_values`) for fixed observations and actions, through
//! `agent/tests/python_critic.py` (the conditioned run's critics carry their features
//! to every layer, the probe's most intricate path).
//!
//! No learning bar: both sides must agree on whatever weights a short run ends with.
//! One tolerance, `FLOAT_NOISE` (1e-5), bounds the actions' difference and each
//! return's relative difference: a return is made by the actions in a closed loop of
//! 200 steps, so it cannot be asked to agree more closely than they do. Returns had a
//! bar of 1e-6 relative until the conditioned preset's Polyak targets (2026-11-30)
//! trained seed 1 to a policy whose action_norm return differed by 3.4e-4 on 78.7
//! (4.3e-6 relative). Seeds 0-5 (`scripts/learning_seeds.sh "0 1 2 3 4 5"
//! python_policy`, 2026-11-30, the conditioned case with its features on every layer
//! of the policy and the critics): actions differed by at most 8.9e-7 (DST's by 0;
//! the conditioned policy's by 3.0e-7), returns by at most 7.1e-4 absolute and 8.0e-7
//! relative, and every report's means were its episodes'. The critic check's bar
//! (`critics_agree`) held on seeds 0-5 (2026-12-02, `MO_MPO_TEST_SEED=S cargo test
//! --workspace --test python_policy`, the three Gaussian runs each): Q differed by
//! 8.1e-8 to 1.9e-7 of the head's largest |Q|. Those ran on an AMD EPYC; on an Intel
//! Xeon both bars held for seeds 0-5 again (2026-12-07, MO_MPO_TEST_SEED,
//! `scripts/learning_seeds.sh "0 1 2 3 4 5" python_policy`): actions
//! differed by at most 8.6e-7, returns by 9.6e-4 absolute and 1.1e-6 relative, and Q by
//! 8.1e-8 to 2.1e-7 of the head's largest |Q|. With the conditioned preset's looser
//! bound on the mean (beta_mean 1e-2) both bars held for seeds 0-5 on the Intel Xeon
//! (2026-12-07, the same command): actions within 8.6e-7, Q within 8.1e-8 to 2.1e-7,
//! returns within 4.6e-5 absolute and 2.0e-7 relative but for the conditioned run of
//! seed 3, where a return differed by 7.3e-3 (9.4e-6 relative, the closed loop
//! amplifying actions that differed by 3.6e-7): the nearest any seed has come to the
//! bar. On an AMD EPYC with beta_mean 1e-2 (2026-12-07, the same command, in a fresh
//! clone after the test command) both bars held for seeds 0-5: actions within 8.9e-7,
//! Q within 8.1e-8 to 2.0e-7, returns within 6.9e-4 absolute and 7.7e-7 relative but
//! for the conditioned run of seed 3 again, 4.8e-3 apart (6.2e-6 relative).

mod cli;
mod common;
mod seed;

/// Float noise allowed between the agent and PyTorch: on actions, absolute; on
/// returns, relative to the return (at least 1).
const FLOAT_NOISE: f64 = 1e-5;

use std::path::Path;
use std::process::Command;

use agent::core::algo::Learner;
use agent::core::nets::ActionKind;
use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::checkpoint::run::{RunProgress, latest_checkpoint, write_run_checkpoint};
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train};
use cli::{python_json, succeeds};
use tch::{Device, Kind, Tensor};

/// `n` observations of `dim` values spread over [-scale, scale] (no two rows alike), so
/// the network's tanh, LayerNorm and clipping see more than one regime.
fn observations(n: usize, dim: usize, scale: f64) -> Vec<Vec<f32>> {
    (0..n)
        .map(|i| {
            (0..dim)
                .map(|j| (scale * (1.7 * i as f64 + 0.9 * j as f64 + 0.3).sin()) as f32)
                .collect()
        })
        .collect()
}

/// Train `cfg` on `server`, have the agent and Python act on `obs` (written as
/// `obs.<ext>`), and evaluate through both; asserts what the module doc says. An
/// ε-conditioned run acts and is evaluated at `epsilon` (`NAME=EPS,...`).
async fn agent_and_python_agree(
    cfg: TrainConfig,
    server: &LocalServer,
    obs: &[Vec<f32>],
    ext: &str,
    epsilon: Option<&str>,
) {
    let address = server.address().to_string();
    let mut cfg = cfg;
    cfg.seed += seed::test_seed();
    let (cfg_seed, env_id, num_envs) = (cfg.seed, cfg.env.id.clone(), cfg.env.num_envs);
    let run = train(cfg, std::slice::from_ref(&address), TrainOptions::default())
        .await
        .unwrap()
        .run_dir;
    let dir = run.parent().unwrap();
    let obs_path = dir.join(format!("obs.{ext}"));
    let actions_path = dir.join(format!("actions.{ext}"));
    if ext == "npy" {
        let flat: Vec<f32> = obs.iter().flatten().copied().collect();
        Tensor::from_slice(&flat)
            .view([obs.len() as i64, obs[0].len() as i64])
            .write_npy(&obs_path)
            .unwrap();
    } else {
        std::fs::write(&obs_path, serde_json::to_string(obs).unwrap()).unwrap();
    }
    agent_act(&run, &obs_path, &actions_path, epsilon);

    let episodes = 4;
    // agent/src/runtime/eval.rs: seeds disjoint from training's, at most env.num_envs instances.
    let seed = cfg_seed + 1_000_000;
    let num_envs = episodes.clamp(1, num_envs);
    let mut args: Vec<String> = epsilon.map_or(vec![], |e| vec!["--epsilon".into(), e.into()]);
    args.extend([&run, &obs_path, &actions_path].map(|p| p.display().to_string()));
    args.extend([address.clone(), env_id.clone()]);
    args.extend([episodes, seed as usize, num_envs].map(|v| v.to_string()));
    let python = python_json("python_policy.py", &args);
    let diff = python["max_abs_diff"].as_f64().unwrap();
    assert!(
        diff <= FLOAT_NOISE,
        "Python's actions differ from the agent's by {diff}"
    );
    let critic_diff = critics_agree(&run);

    let report = agent_eval(&run, &address, episodes, epsilon, &dir.join("eval.json"));
    let episodes_agent = report["episodes"].as_array().unwrap();
    // The report's means are its episodes' means.
    for (k, mean) in report["mean_return"].as_array().unwrap().iter().enumerate() {
        let returns: Vec<f64> = episodes_agent
            .iter()
            .map(|e| e["episode_return"][k].as_f64().unwrap())
            .collect();
        let expected = returns.iter().sum::<f64>() / returns.len() as f64;
        assert!((mean.as_f64().unwrap() - expected).abs() <= 1e-9 * expected.abs().max(1.0));
    }
    let theirs = python["episodes"].as_array().unwrap();
    assert_eq!(theirs.len(), episodes_agent.len());
    let mut largest_return_diff = 0.0f64;
    let mut largest_relative_diff = 0.0f64;
    for (agent, python) in episodes_agent.iter().zip(theirs) {
        assert_eq!(python["env_index"], agent["env_index"]);
        assert_eq!(python["length"], agent["length"]);
        let returns: Vec<f64> = serde_json::from_value(python["episode_return"].clone()).unwrap();
        let agent_returns: Vec<f64> =
            serde_json::from_value(agent["episode_return"].clone()).unwrap();
        for (p, a) in returns.iter().zip(&agent_returns) {
            largest_return_diff = largest_return_diff.max((p - a).abs());
            largest_relative_diff = largest_relative_diff.max((p - a).abs() / a.abs().max(1.0));
            // The same seeded envs driven by actions equal up to float noise.
            assert!(
                (p - a).abs() <= FLOAT_NOISE * a.abs().max(1.0),
                "episode returns: agent {agent_returns:?}, Python {returns:?}"
            );
        }
    }
    seed::report_figures(
        &format!("{env_id} {}", epsilon.unwrap_or("")),
        &format!(
            "action diff {diff:.1e} return diff {largest_return_diff:.1e} \
             (relative {largest_relative_diff:.1e}) critic diff {}",
            critic_diff.map_or("none (discrete)".into(), |d| format!("{d:.1e}"))
        ),
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dst_policy_in_pytorch_acts_and_returns_as_the_agent() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst.toml");
    let mut cfg = TrainConfig::load_with(&path, &["run.total_env_steps=2000".into()]).unwrap();
    cfg.run.runs_dir = runs.path().join("runs");
    // DST observes the submarine's (row, column) in a 11 x 10 grid.
    agent_and_python_agree(cfg, &server, &observations(64, 2, 10.0), "json", None).await;
}

/// `configs/mompo/<file>` cut to 1,600 env steps and one evaluation episode, with
/// `more` settings, its runs under `dir/runs`.
fn short_pendulum(file: &str, dir: &Path, more: &[&str]) -> TrainConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs/mompo")
        .join(file);
    let mut sets = vec![
        "run.total_env_steps=1600".to_string(),
        "run.min_replay_transitions=400".into(),
        "run.eval_episodes=1".into(),
    ];
    sets.extend(more.iter().map(|s| s.to_string()));
    let mut cfg = TrainConfig::load_with(&path, &sets).unwrap();
    cfg.run.runs_dir = dir.join("runs");
    cfg
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_epsilon_conditioned_policy_in_pytorch_acts_and_returns_as_the_agent() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    // Its features carried to every layer of the policy and of the critics (which
    // PyTorch does not load, but the run trains and checkpoints): the preset's
    // input-only torso is the plain pendulum test's, on an observation with the
    // features appended as here. The bar held on seeds 0-5 (2026-11-30,
    // `scripts/learning_seeds.sh "0 1 2 3 4 5" python_policy`): actions within 3.0e-7,
    // returns within 7.1e-4 (8.0e-7 relative). With the preset's beta_mean 1e-2 it held
    // for seeds 0-5 on an Intel Xeon (2026-12-07, the same command): actions within
    // 4.0e-7, 3.0e-7, 2.2e-7, 3.6e-7, 4.3e-7, 4.9e-7 and returns within 1.6e-8,
    // 2.4e-8, 6.1e-8, 9.4e-6, 7.1e-8, 1.4e-7 relative (seeds 0-5; seed 3's is the
    // module doc's closed-loop case). On an AMD EPYC (2026-12-07): actions within
    // 2.4e-7, 2.4e-7, 2.6e-7, 2.7e-7, 3.8e-7, 2.8e-7 and returns within 1.7e-8,
    // 2.2e-8, 2.2e-8, 6.2e-6, 9.2e-8, 6.4e-8 relative: seed 3 again the closest.
    let every_layer = [
        r#"learner.network.policy_preference="every_layer""#,
        r#"learner.network.critic_preference="every_layer""#,
    ];
    let cfg = short_pendulum("pendulum-conditioned.toml", runs.path(), &every_layer);
    // The env's (cos θ, sin θ, θ') only: both sides append the feature of ε_action_norm
    // 0.02, between grid points, and a Gaussian mean moves with any change of its input,
    // so a feature computed differently shows in the actions.
    let obs = observations(64, 3, 8.0);
    agent_and_python_agree(cfg, &server, &obs, "json", Some("action_norm=0.02")).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pendulum_policy_in_pytorch_acts_and_returns_as_the_agent() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let cfg = short_pendulum("pendulum.toml", runs.path(), &[]);
    // Pendulum observes (cos θ, sin θ, θ') with |θ'| <= 8: a wider range saturates tanh.
    agent_and_python_agree(cfg, &server, &observations(64, 3, 8.0), "npy", None).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_state_independent_std_policy_in_pytorch_acts_and_returns_as_the_agent() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let runs = tempfile::tempdir().unwrap();
    let std = r#"learner.network.policy_std="state_independent""#;
    let cfg = short_pendulum("pendulum.toml", runs.path(), &[std]);
    agent_and_python_agree(cfg, &server, &observations(64, 3, 8.0), "npy", None).await;
}

/// `scripts/probe_critic.py`'s transcription of the Q critics gives the agent's Q
/// (`Learner::q_values`) on `run`'s latest checkpoint, within `FLOAT_NOISE` of
/// max(1, the head's largest |Q| over the inputs): at observations of the learner's
/// input width (a conditioned run's feature columns take any values here, since both
/// sides must agree on any input) and actions past the bounds (the critics see tanh of
/// the action). Continuous actions only, as the probe; returns the largest relative
/// difference.
///
/// Relative to the head's scale, not to each Q: float32 rounding in the layers' sums
/// follows the size of the values summed, and measured per Q (over max(1, |Q|)) seed
/// 2's conditioned run differed by 5.7e-6 at a Q near 2.7 where the head reached 155,
/// one float32 step at that scale (1.5e-5). Seeds 0-5: the module's doc. A
/// transcription with ReLU for the heads' ELU failed by 0.056-0.087 (all three
/// Gaussian runs).
fn critics_agree(run: &Path) -> Option<f64> {
    let (checkpoint, _) = latest_checkpoint(run).unwrap();
    let learner = Learner::load_checkpoint(&checkpoint, Device::Cpu).unwrap();
    let ActionKind::Continuous { dim } = learner.dims().action else {
        return None;
    };
    let (n, m, width) = (32, 5, learner.dims().obs_dim as usize);
    let obs: Vec<f32> = observations(n, width, 3.0).concat();
    let obs = Tensor::from_slice(&obs).view([1, n as i64, width as i64]);
    // Action j of sample k at state i: 1.5 sin(0.7 k + 1.3 i + 0.4 j).
    let index =
        |size: i64, shape: [i64; 4]| Tensor::arange(size, (Kind::Double, Device::Cpu)).view(shape);
    let phase = index(m, [1, m, 1, 1]) * 0.7
        + index(n as i64, [1, 1, n as i64, 1]) * 1.3
        + index(dim, [1, 1, 1, dim]) * 0.4;
    let actions = (phase.sin() * 1.5).to_kind(Kind::Float);
    let q = learner
        .q_values(&obs, &actions)
        .expect("MO-MPO has Q critics");
    let dir = run.parent().unwrap();
    let files = [("obs", obs), ("actions", actions), ("q", q)].map(|(name, t)| {
        let path = dir.join(format!("critic_{name}.npy"));
        t.squeeze_dim(0).write_npy(&path).unwrap();
        path
    });
    let mut args = vec![checkpoint];
    args.extend(files);
    let python = python_json("python_critic.py", &args);
    let relative = python["max_relative_diff"].as_f64().unwrap();
    assert!(
        relative <= FLOAT_NOISE,
        "probe_critic.py's Q differs from the agent's by {relative} of the head's largest \
         |Q| ({python})"
    );
    Some(relative)
}

/// `agent eval` (the real binary) of `run` through `address`, its `--json` report.
fn agent_eval(
    run: &Path,
    address: &str,
    episodes: usize,
    epsilon: Option<&str>,
    json: &Path,
) -> serde_json::Value {
    succeeds(
        Command::new(env!("CARGO_BIN_EXE_agent"))
            .args(["eval", "--checkpoint"])
            .arg(run)
            .args(["--server", address, "--episodes", &episodes.to_string()])
            .args(epsilon.map_or(vec![], |e| vec!["--epsilon", e]))
            .arg("--json")
            .arg(json),
    );
    serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap()
}

/// `agent act` (the real binary) on `obs`, writing `actions`, at `epsilon` if given.
fn agent_act(run: &Path, obs: &Path, actions: &Path, epsilon: Option<&str>) {
    succeeds(
        Command::new(env!("CARGO_BIN_EXE_agent"))
            .args(["act", "--checkpoint"])
            .arg(run)
            .arg("--observations")
            .arg(obs)
            .arg("--out")
            .arg(actions)
            .args(epsilon.map_or(vec![], |e| vec!["--epsilon", e])),
    );
}

#[test]
fn a_mocap_policy_in_pytorch_acts_as_the_agent() {
    let learner = common::movmpo_mocap_learner();
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    // The run's config.toml, which `agent act` builds the policy from: any run config
    // with this learner's settings.
    let smoke = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst.toml");
    let mut cfg = TrainConfig::load(&smoke).unwrap();
    cfg.learner = learner.config().clone();
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("config.toml"), toml::to_string(&cfg).unwrap()).unwrap();
    let progress = RunProgress::learner_only(learner.step_count());
    write_run_checkpoint(&run, &learner, 0, &progress, None).unwrap();
    // Leaves walker/joints (1) and walker/reference_pos (2): proprioception is index 0.
    let obs = observations(32, common::OBS as usize, 3.0);
    let obs_path = dir.path().join("obs.json");
    std::fs::write(&obs_path, serde_json::to_string(&obs).unwrap()).unwrap();
    let actions_path = dir.path().join("actions.json");
    agent_act(&run, &obs_path, &actions_path, None);
    let python = python_json("python_policy.py", &[&run, &obs_path, &actions_path]);
    let diff = python["max_abs_diff"].as_f64().unwrap();
    assert!(
        diff <= FLOAT_NOISE,
        "Python's actions differ from the agent's by {diff}"
    );
}
