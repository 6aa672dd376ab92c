//! End-to-end: a real env_server process and the Rust client over loopback gRPC.
//!
//! Rewards are checked against the task definitions (paper appendix B.1, B.3),
//! not against values the server produced earlier.

use agent::core::spec::{AutoresetMode, Space};
use agent::env::error::StatusKind;
use agent::env::grpc::EnvClient;
use agent::env::server_process::{LocalServer, ServerOptions};
use agent::env::{Env, HostTensor, MakeOptions, random_action};
use integration_tests::Harness;
use rand::SeedableRng;

/// Deep Sea Treasure (paper B.1, values of Yang et al. 2019): (row, col, value).
/// Row 0 is the surface, so "right c times, then down r times" is a shortest path
/// of c + r steps to the treasure of column c: exactly the true Pareto front.
const TREASURES: [(usize, usize, f32); 10] = [
    (1, 0, 0.7),
    (2, 1, 8.2),
    (3, 2, 11.5),
    (4, 3, 14.0),
    (4, 4, 15.1),
    (4, 5, 16.1),
    (7, 6, 19.6),
    (7, 7, 20.3),
    (9, 8, 22.4),
    (10, 9, 23.7),
];
const UP: i64 = 0;
const RIGHT: i64 = 1;
const DOWN: i64 = 2;

fn dst_path(col: usize) -> Vec<i64> {
    let (row, _, _) = TREASURES[col];
    std::iter::repeat_n(RIGHT, col)
        .chain(std::iter::repeat_n(DOWN, row))
        .collect()
}

async fn run_dst_paths(client: &EnvClient, num_envs: usize, stream: bool) -> Vec<Vec<f32>> {
    let mut env = client
        .make(&MakeOptions {
            seed: Some(7),
            ..MakeOptions::new("dst", num_envs)
        })
        .await
        .unwrap();
    if stream {
        env.use_stream();
    }
    assert_eq!(env.spec().objective_names(), ["time", "treasure"]);
    assert_eq!(env.spec().max_episode_steps, Some(200));
    env.reset(&[], &[]).await.unwrap();
    let paths: Vec<Vec<i64>> = (0..num_envs).map(dst_path).collect();
    let longest = paths.iter().map(Vec::len).max().unwrap();
    let mut rewards = Vec::new();
    let mut ended = vec![false; num_envs];
    for t in 0..longest {
        let actions: Vec<i64> = paths
            .iter()
            .map(|p| p.get(t).copied().unwrap_or(UP))
            .collect();
        let step = env
            .step(&HostTensor::from_i64(vec![num_envs], &actions))
            .await
            .unwrap();
        for (i, path) in paths.iter().enumerate() {
            if ended[i] {
                continue;
            }
            let r = &step.reward[i * 2..i * 2 + 2];
            assert_eq!(r[0], -1.0, "time reward of instance {i} at step {t}");
            let arrives = t + 1 == path.len();
            let expected_treasure = if arrives { TREASURES[i].2 } else { 0.0 };
            assert!(
                (r[1] - expected_treasure).abs() < 1e-6,
                "treasure of instance {i} at step {t}: {r:?}"
            );
            assert_eq!(
                step.terminated[i], arrives,
                "terminated of instance {i} at step {t}"
            );
            assert!(!step.truncated[i]);
            if arrives {
                ended[i] = true;
                let episode = step
                    .episodes
                    .iter()
                    .find(|e| e.env_index == i)
                    .expect("episode summary");
                assert_eq!(episode.length as usize, path.len());
                assert_eq!(episode.episode_return[0], -(path.len() as f64));
                assert!((episode.episode_return[1] - f64::from(TREASURES[i].2)).abs() < 1e-5);
                // Σ_t γ^t r_t with γ = 0.99 (the server default).
                let gamma: f64 = env.spec().discount;
                let time: f64 = (0..path.len()).map(|k| -gamma.powi(k as i32)).sum();
                assert!((episode.discounted_return[0] - time).abs() < 1e-9);
                let treasure = f64::from(TREASURES[i].2) * gamma.powi(path.len() as i32 - 1);
                assert!((episode.discounted_return[1] - treasure).abs() < 1e-5);
                // SAME_STEP: the returned observation is the new episode's start.
                let obs = step.observation.to_flat_f32();
                assert_eq!(&obs[i * 2..i * 2 + 2], &[0.0, 0.0]);
            }
        }
        rewards.push(step.reward);
    }
    assert!(ended.iter().all(|&e| e));
    env.close().await.unwrap();
    rewards
}

#[tokio::test]
async fn dst_over_the_wire_matches_the_paper_definition_for_b1_and_b8() {
    let h = Harness::start(&[]).await;
    run_dst_paths(&h.client, 1, false).await;
    let unary = run_dst_paths(&h.client, 8, false).await;
    let streamed = run_dst_paths(&h.client, 8, true).await;
    assert_eq!(
        unary, streamed,
        "StepStream and unary Step give the same rewards"
    );
    h.server.stop().await.unwrap();
}

#[tokio::test]
async fn humanoid_run_rewards_follow_their_definitions_for_b1_and_b8() {
    let h = Harness::start(&[]).await;
    for num_envs in [1, 8] {
        let options = MakeOptions {
            seed: Some(3),
            ..MakeOptions::new("humanoid-run", num_envs)
        };
        let mut env = h.client.make(&options).await.unwrap();
        let spec = env.spec().clone();
        assert_eq!(spec.objective_names(), ["task", "action_norm"]);
        assert_eq!(spec.observation_space.flat_dim(), 67);
        let Space::Box(action_space) = &spec.action_space else {
            panic!("humanoid-run has Box actions")
        };
        assert_eq!(action_space.shape, [21]);
        assert!(
            action_space.low.iter().all(|&l| l == -1.0)
                && action_space.high.iter().all(|&h| h == 1.0)
        );
        let reset = env.reset(&[], &[]).await.unwrap();
        assert_eq!(reset.observation.to_flat_f32().len(), num_envs * 67);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        // B=1 runs the whole 1000-step episode to see its truncation; B=8 a short stretch.
        let steps = if num_envs == 1 { 1000 } else { 40 };
        for t in 0..steps {
            let action = random_action(&spec.action_space, num_envs, &mut rng);
            let a = action.to_f32_vec();
            let step = env.step(&action).await.unwrap();
            for i in 0..num_envs {
                let norm = a[i * 21..(i + 1) * 21]
                    .iter()
                    .map(|x| x * x)
                    .sum::<f32>()
                    .sqrt();
                let (task, action_norm) = (step.reward[i * 2], step.reward[i * 2 + 1]);
                assert!(
                    (action_norm + norm).abs() < 1e-5,
                    "action_norm {action_norm} vs -||a|| {norm}"
                );
                assert!(
                    (0.0..=1.0).contains(&task),
                    "task reward {task} outside [0, 1]"
                );
                assert!(!step.terminated[i], "humanoid run never terminates");
                assert_eq!(
                    step.truncated[i],
                    t == 999,
                    "truncation only at the 1000-step limit"
                );
            }
            if t == 999 {
                let e = &step.episodes[0];
                assert_eq!((e.length, e.truncated, e.terminated), (1000, true, false));
            }
        }
        env.close().await.unwrap();
    }
    h.server.stop().await.unwrap();
}

#[tokio::test]
async fn humanoid_run_in_server_worker_processes_steps_exactly_as_without() {
    // More workers than this machine may have CPUs: correctness does not depend on it.
    let h = Harness::start(&["--max-workers", "3"]).await;
    let mut runs = Vec::new();
    for num_workers in [0, 1, 3] {
        let options = MakeOptions {
            seed: Some(5),
            num_workers,
            ..MakeOptions::new("humanoid-run", 4)
        };
        let mut env = h.client.make(&options).await.unwrap();
        env.use_stream();
        let mut seen = env.reset(&[], &[]).await.unwrap().observation.to_flat_f32();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        for _ in 0..30 {
            let action = random_action(&env.spec().action_space, 4, &mut rng);
            let step = env.step(&action).await.unwrap();
            seen.extend(step.observation.to_flat_f32());
            seen.extend(&step.reward);
        }
        env.close().await.unwrap();
        runs.push(seen);
    }
    // Bit for bit: the same simulator states, whichever process stepped them.
    assert_eq!(runs[0], runs[1], "1 worker");
    assert_eq!(runs[0], runs[2], "3 workers");
    h.server.stop().await.unwrap();
}

#[tokio::test]
async fn server_errors_arrive_typed_with_the_servers_message() {
    let h = Harness::start(&["--max-sessions", "2"]).await;
    let err = h
        .client
        .make(&MakeOptions::new("no-such-env", 1))
        .await
        .unwrap_err();
    assert_eq!(err.status_kind(), Some(StatusKind::NotFound), "{err}");
    assert!(err.to_string().contains("no-such-env"), "{err}");

    let mut env = h.client.make(&MakeOptions::new("dst", 2)).await.unwrap();
    let err = env
        .step(&HostTensor::from_i64(vec![2], &[0, 1]))
        .await
        .unwrap_err();
    assert_eq!(
        err.status_kind(),
        Some(StatusKind::FailedPrecondition),
        "{err}"
    );
    env.reset(&[], &[]).await.unwrap();
    let err = env
        .step(&HostTensor::from_i64(vec![3], &[0, 1, 2]))
        .await
        .unwrap_err();
    assert_eq!(
        err.status_kind(),
        Some(StatusKind::InvalidArgument),
        "{err}"
    );
    assert!(
        err.to_string().contains("[2]") && err.to_string().contains("[3]"),
        "names expected and got: {err}"
    );
    let err = env
        .step(&HostTensor::from_f32(vec![2], &[0.0, 1.0]))
        .await
        .unwrap_err();
    assert_eq!(
        err.status_kind(),
        Some(StatusKind::InvalidArgument),
        "{err}"
    );
    assert!(
        err.to_string().contains("int64") && err.to_string().contains("float32"),
        "{err}"
    );
    let err = env
        .step(&HostTensor::from_i64(vec![2], &[0, 4]))
        .await
        .unwrap_err();
    assert_eq!(
        err.status_kind(),
        Some(StatusKind::InvalidArgument),
        "{err}"
    );

    let _second = h.client.make(&MakeOptions::new("dst", 1)).await.unwrap();
    let err = h
        .client
        .make(&MakeOptions::new("dst", 1))
        .await
        .unwrap_err();
    assert_eq!(
        err.status_kind(),
        Some(StatusKind::ResourceExhausted),
        "{err}"
    );

    env.close().await.unwrap();
    h.server.stop().await.unwrap();
}

#[tokio::test]
async fn disabled_autoreset_requires_an_explicit_reset() {
    let h = Harness::start(&[]).await;
    let options = MakeOptions {
        autoreset_mode: AutoresetMode::Disabled,
        ..MakeOptions::new("dst", 2)
    };
    let mut env = h.client.make(&options).await.unwrap();
    env.reset(&[], &[]).await.unwrap();
    // Instance 0 reaches the 0.7 treasure in one step; instance 1 does not move.
    let step = env
        .step(&HostTensor::from_i64(vec![2], &[DOWN, UP]))
        .await
        .unwrap();
    assert_eq!(step.terminated, [true, false]);
    let err = env
        .step(&HostTensor::from_i64(vec![2], &[UP, UP]))
        .await
        .unwrap_err();
    assert_eq!(
        err.status_kind(),
        Some(StatusKind::FailedPrecondition),
        "{err}"
    );
    let reset = env.reset(&[0], &[]).await.unwrap();
    assert_eq!(reset.observation.to_flat_f32(), [0.0, 0.0]);
    env.step(&HostTensor::from_i64(vec![2], &[UP, UP]))
        .await
        .unwrap();
    env.close().await.unwrap();
    h.server.stop().await.unwrap();
}

#[tokio::test]
async fn client_rides_out_a_server_restart_on_the_same_port() {
    let first = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let port = first.port();
    let client = EnvClient::connect(first.address()).await.unwrap();
    assert!(
        client
            .list_envs()
            .await
            .unwrap()
            .iter()
            .any(|e| e.env_id == "dst")
    );
    first.kill().await.unwrap();
    // Restart on the same port a moment later; the next call sees UNAVAILABLE
    // until then and is retried with backoff.
    let restarted = tokio::spawn(async move {
        tokio::time::sleep(std::time::Duration::from_millis(500)).await;
        LocalServer::start(&ServerOptions {
            port,
            ..ServerOptions::default()
        })
        .await
        .unwrap()
    });
    let envs = client
        .list_envs()
        .await
        .expect("retried until the server was back");
    assert!(envs.iter().any(|e| e.env_id == "humanoid-run"));
    restarted.await.unwrap().stop().await.unwrap();
}
