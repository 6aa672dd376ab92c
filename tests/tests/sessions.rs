//! A run whose env crashes leaves no session open on the server.
//!
//! The server keeps a session whose simulator raised (it answers INTERNAL and goes on
//! serving), so only the agent can give it back before its lease runs out. The server
//! here allows one session at a time: a Make after the failed run succeeds only if
//! the run closed every session it made (the spec probe's and the actor's).

use std::collections::BTreeMap;
use std::path::Path;

use agent::core::learner_config::{ObjectiveConfig, ObjectiveSource};
use agent::env::grpc::EnvClient;
use agent::env::server_process::{LocalServer, ServerOptions};
use agent::env::{Env, MakeOptions};
use agent::runtime::train::{TrainOptions, train};
use integration_tests::smoke_config;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_whose_env_crashes_leaves_no_session_behind() {
    // env_server's test plug-ins: `faulty` raises RuntimeError when it is sent action 3,
    // which a fresh categorical policy sends within a few steps.
    let plugins = Path::new(env!("CARGO_MANIFEST_DIR")).join("../env_server/tests/plugins");
    let server = LocalServer::start(&ServerOptions {
        extra_args: vec!["--max-sessions".into(), "1".into()],
        environment: BTreeMap::from([("PYTHONPATH".into(), plugins.display().to_string())]),
        ..ServerOptions::default()
    })
    .await
    .unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut cfg = smoke_config(runs.path());
    cfg.env.id = "faulty".into();
    cfg.env.num_envs = 4;
    cfg.learner.objectives = vec![ObjectiveConfig {
        name: "steps".into(),
        epsilon: 0.1,
        source: ObjectiveSource::Learned,
    }];
    let err = train(
        cfg,
        &[server.address().to_string()],
        TrainOptions::default(),
    )
    .await
    .expect_err("the env raises on action 3");
    assert!(
        err.to_string().contains("exploded"),
        "the run's error names the env's: {err}"
    );
    let client = EnvClient::connect(server.address()).await.unwrap();
    let env = client
        .make(&MakeOptions::new("dst", 1))
        .await
        .expect("the failed run closed its sessions, so the one allowed session is free");
    env.close().await.unwrap();
    server.stop().await.unwrap();
}
