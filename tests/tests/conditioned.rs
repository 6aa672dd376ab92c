//! ε-conditioned MO-MPO end to end over a real server (issue 26): one run of
//! `configs/smoke/dst-conditioned.toml` learns three ε_treasure / ε_time ratios, ends
//! by writing its front, and `agent eval --epsilon` and `agent act --epsilon` ask its
//! policy for any preference.

use std::collections::BTreeMap;
use std::path::Path;

use agent::env::connection::ConnectionConfig;
use agent::env::server_process::{LocalServer, ServerOptions};
use agent::runtime::eval::evaluate_checkpoint_at;
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_run_traces_a_front_over_its_preference_grid() {
    let server = LocalServer::start(&ServerOptions::default()).await.unwrap();
    let address = [server.address().to_string()];
    let runs = tempfile::tempdir().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst-conditioned.toml");
    let mut cfg = TrainConfig::load(&path).unwrap();
    cfg.run.runs_dir = runs.path().to_path_buf();
    let cfg = integration_tests::with_seed(cfg, integration_tests::test_seed());
    let summary = train(cfg, &address, TrainOptions::default()).await.unwrap();
    let front = summary.front.expect("a conditioned run measures its front");
    let dir = summary.run_dir.join("front");
    for file in [
        "points.csv",
        "front.csv",
        "summary.json",
        "front.png",
        "returns.png",
    ] {
        assert!(dir.join(file).exists(), "front/{file} missing");
    }
    // Every training episode says which preference it acted with.
    let episodes = std::fs::read_to_string(summary.run_dir.join("episodes.csv")).unwrap();
    let header = episodes.lines().next().unwrap();
    assert!(header.ends_with(",epsilon_treasure"), "{header}");
    let drawn: std::collections::BTreeSet<&str> = episodes
        .lines()
        .skip(1)
        .map(|l| l.rsplit(',').next().unwrap())
        .collect();
    assert_eq!(drawn, ["0.005", "0.05", "0.5"].into_iter().collect());
    // One point per grid value, in grid order, each with every objective's ε.
    let settings: Vec<f64> = front.points.iter().map(|p| p.setting["treasure"]).collect();
    assert_eq!(settings, vec![0.005, 0.05, 0.5]);
    assert!(front.points.iter().all(|p| p.setting["time"] == 0.02));
    // The preference is followed: a larger ε_treasure / ε_time never settles for a
    // nearer treasure, and the ratios 0.25 and 25 end at different treasures (on DST
    // the deterministic policy's treasure return names the treasure it reached).
    let treasure: Vec<f64> = front.points.iter().map(|p| p.eval_return[1]).collect();
    integration_tests::report_figures("conditioned_front", &format!("treasures {treasure:?}"));
    // Both bars held for seeds 1-5 (MO_MPO_TEST_SEED, scripts/learning_seeds.sh),
    // treasure at ε_treasure 0.005 / 0.05 / 0.5:
    // 1: 0.7 / 0.7 / 15.1, 2: 0.7 / 0.7 / 14.0, 3: 0.7 / 0.7 / 15.1,
    // 4: 0.7 / 8.2 / 15.1, 5: 0.7 / 0.7 / 14.0.
    assert!(
        treasure.windows(2).all(|w| w[1] >= w[0]),
        "treasure reached against ε_treasure: {treasure:?}"
    );
    assert!(
        treasure[2] > treasure[0],
        "one policy for every ratio: {treasure:?}"
    );
    assert!(front.hypervolume > 0.0);

    // `agent eval --epsilon`: the grid point gives the front's return; a preference
    // off the grid is evaluated too; a name that is not conditioned is refused.
    let connection = ConnectionConfig::default();
    let at = |v: f64| BTreeMap::from([("treasure".to_string(), v)]);
    let on_grid = evaluate_checkpoint_at(
        &summary.run_dir,
        Some(&at(0.5)),
        &address,
        &connection,
        1,
        None,
    )
    .await
    .unwrap();
    assert_eq!(on_grid.mean_return, front.points[2].eval_return);
    let off_grid = evaluate_checkpoint_at(
        &summary.run_dir,
        Some(&at(0.2)),
        &address,
        &connection,
        1,
        None,
    )
    .await
    .unwrap();
    assert_eq!(off_grid.mean_return.len(), 2);
    let time = BTreeMap::from([("time".to_string(), 0.1)]);
    let err = evaluate_checkpoint_at(
        &summary.run_dir,
        Some(&time),
        &address,
        &connection,
        1,
        None,
    )
    .await
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("--epsilon") && err.contains("\"time\" is not a conditioned objective"),
        "{err}"
    );

    // `agent act --epsilon` takes the env's observations (every cell of the grid) and
    // appends the preference itself: the ratios 0.25 and 25, which reach different
    // treasures, act differently somewhere; observations that already carry a
    // feature are refused with the env's size.
    let cells: Vec<[f32; 2]> = (0..11)
        .flat_map(|r| (0..10).map(move |c| [r as f32, c as f32]))
        .collect();
    let observations = runs.path().join("cells.json");
    std::fs::write(&observations, serde_json::to_string(&cells).unwrap()).unwrap();
    let act = |v: f64| {
        agent::runtime::act::act_on_file(&summary.run_dir, &observations, None, Some(&at(v)))
            .unwrap()
            .unwrap()
    };
    let (near, far) = (act(0.005), act(0.5));
    let actions: Vec<i64> = serde_json::from_str(&near).unwrap();
    assert_eq!(actions.len(), cells.len());
    assert_ne!(near, far, "the same actions at ratios 0.25 and 25");
    let with_feature = runs.path().join("with_feature.json");
    std::fs::write(&with_feature, "[[0, 0, 0.5]]").unwrap();
    let err = agent::runtime::act::act_on_file(&summary.run_dir, &with_feature, None, None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("expected shape [B, 2]"), "{err}");
    server.stop().await.unwrap();
}

#[test]
fn a_conditioned_config_names_its_grid_and_front() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/smoke/dst-conditioned.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let load = |text: &str| {
        let file = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(file.path(), text).unwrap();
        TrainConfig::load(file.path())
            .map(|_| ())
            .unwrap_err()
            .to_string()
    };
    let cases = [
        (
            text.replace("treasure = [0.005, 0.05, 0.5]", "treasure = [0.0, 0.05]"),
            "learner.conditioning.epsilon.treasure must be ε values > 0",
        ),
        (
            text.replace("{ treasure = [", "{ gold = ["),
            "learner.conditioning.epsilon.gold must be one of learner.objectives",
        ),
        (
            text.replace("kind = \"mo_mpo\"", "kind = \"mo_vmpo\""),
            "learner.conditioning must be used with algorithm.kind = \"mo_mpo\" only",
        ),
        (
            text[..text.find("[front]").unwrap()].to_string(),
            "front must be a [front] section",
        ),
    ];
    for (bad, says) in cases {
        let err = load(&bad);
        assert!(err.contains(says), "wanted {says:?}, got {err}");
    }
}
