//! Every shipped config loads, validates, and binds its objectives by name to the
//! objectives the real env declares, closed-form sources included (one generic test
//! over `configs/`).

use std::path::{Path, PathBuf};

use agent::core::algo::objectives::{LearnerDims, bind_config, check_declared};
use agent::env::{Env, MakeOptions};
use agent::runtime::run_config::TrainConfig;
use agent::sweep::SweepConfig;
use integration_tests::Harness;

fn files(dir: &str) -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs")
        .join(dir);
    let mut out: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    out.sort();
    out
}

#[tokio::test]
async fn every_run_config_binds_to_its_envs_objectives() {
    let h = Harness::start(&[]).await;
    let configs: Vec<PathBuf> = ["mompo", "mpo", "movmpo", "vmpo", "smoke"]
        .iter()
        .flat_map(|d| files(d))
        .collect();
    assert!(configs.len() >= 10, "{configs:?}");
    for path in configs {
        let cfg = TrainConfig::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let options = MakeOptions {
            kwargs: cfg.env.kwargs.clone(),
            ..MakeOptions::new(&cfg.env.id, 1)
        };
        let env = h
            .client
            .make(&options)
            .await
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let dims = LearnerDims::from_spec(env.spec()).unwrap();
        bind_config(&cfg.learner, &dims).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        check_declared(&cfg.learner, &env.spec().objectives)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        env.close().await.unwrap();
    }
    h.server.stop().await.unwrap();
}

#[test]
fn every_sweep_config_loads_with_its_base() {
    let sweeps = files("sweeps");
    assert!(sweeps.len() >= 5);
    for path in sweeps {
        let (sweep, _) =
            SweepConfig::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(!sweep.settings().is_empty());
    }
}
