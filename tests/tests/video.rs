//! Videos end to end: `eval --video` of a trained DST run and a `humanoid-run`
//! evaluation (rendered by OpenGL, in software on a CPU-only machine), each decoded
//! back with ffmpeg and checked for its frame count and size.

use std::path::Path;
use std::process::Command;

use agent::core::nets::{ActorPolicy, LearnerDims};
use agent::env::connection::ConnectionConfig;
use agent::env::{Env, MakeOptions};
use agent::report::video::{Layout, VideoOptions, VideoPlan, find_ffmpeg};
use agent::runtime::eval::{evaluate_checkpoint, evaluate_recorded};
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train};
use integration_tests::{Harness, smoke_config};
use tch::Device;

/// (frames, width, height) of a video, by decoding every frame to raw RGB.
fn decode(path: &Path, width: usize, height: usize) -> usize {
    let out = Command::new(find_ffmpeg().expect("ffmpeg from imageio-ffmpeg"))
        .args(["-v", "error", "-i"])
        .arg(path)
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
        .output()
        .expect("ffmpeg runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let frame = width * height * 3;
    assert_eq!(out.stdout.len() % frame, 0, "whole {width}x{height} frames");
    out.stdout.len() / frame
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn eval_video_of_a_dst_run_has_a_frame_per_step_of_the_tiled_instances() {
    let h = Harness::start(&[]).await;
    let runs = tempfile::tempdir().unwrap();
    let mut cfg = smoke_config(runs.path());
    cfg.run.total_env_steps = 1000;
    let address = h.server.address().to_string();
    let options = VideoOptions {
        width: 64,
        height: 48,
        ..VideoOptions::default()
    };
    let plan = VideoPlan {
        every: None,
        options: options.clone(),
    };
    let s = train(
        cfg,
        std::slice::from_ref(&address),
        TrainOptions {
            video: Some(plan),
            ..TrainOptions::default()
        },
    )
    .await
    .unwrap();
    let final_video = s.eval_video.expect("the final evaluation was recorded");
    assert_eq!(final_video.path, s.run_dir.join("videos").join("final.mp4"));

    let path = runs.path().join("eval.mp4");
    let report = evaluate_checkpoint(
        &s.run_dir,
        &[address],
        &ConnectionConfig::default(),
        3,
        Some((path.as_path(), &options)),
    )
    .await
    .unwrap();
    let video = report.video.expect("a video was asked for");
    // Three instances run at once, tiled 2 x 2; one frame after the reset and one per step
    // until the third episode ends.
    let layout = Layout::new(3, 64, 48, 2);
    let steps = report.episodes.iter().map(|e| e.length).max().unwrap() as usize;
    assert_eq!(video.frames, steps + 1);
    assert_eq!(decode(&path, layout.width, layout.height), video.frames);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn humanoid_run_evaluation_video_renders_without_a_gpu() {
    let h = Harness::start(&[]).await;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/mompo/humanoid-run.toml");
    let mut cfg = TrainConfig::load(&path).unwrap();
    // A 1 s episode (40 control steps) keeps the test short.
    cfg.env.kwargs.insert("time_limit".into(), 1.0.into());
    cfg.env.num_envs = 1;
    let make = MakeOptions {
        kwargs: cfg.env.kwargs.clone(),
        ..MakeOptions::new("humanoid-run", 1)
    };
    let env = h.client.make(&make).await.unwrap();
    let dims = LearnerDims::from_spec(env.spec()).unwrap();
    env.close().await.unwrap();
    let policy = ActorPolicy::new(&cfg.learner.network, &dims, Device::Cpu);
    let out = tempfile::tempdir().unwrap();
    let video_path = out.path().join("humanoid.mp4");
    let options = VideoOptions {
        width: 96,
        height: 72,
        ..VideoOptions::default()
    };
    let (episodes, video) = evaluate_recorded(&h.client, &cfg, policy, 1, &video_path, &options)
        .await
        .unwrap();
    assert_eq!(episodes[0].length, 40);
    assert_eq!(video.frames, 41);
    let layout = Layout::new(1, 96, 72, 2);
    assert_eq!(decode(&video_path, layout.width, layout.height), 41);
}
