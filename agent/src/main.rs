//! `agent`: command-line entry point (the only place that uses `anyhow`).
#![allow(clippy::print_stdout, reason = "a CLI prints its results")]

use std::path::PathBuf;
use std::time::Instant;

use agent::config::DeviceChoice;
use agent::env::grpc::{EnvClient, RemoteEnv};
use agent::env::server_process::{LocalServer, ServerOptions};
use agent::env::{Env, MakeOptions, random_action};
use agent::eval::evaluate_checkpoint;
use agent::run_config::TrainConfig;
use agent::sweep::{SweepConfig, sweep};
use agent::train::{TrainOptions, TrainSummary, train};
use agent::video::{VideoOptions, VideoPlan};
use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use rand::SeedableRng;

/// Multi-objective MPO agents for env_server environments.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Train one agent (MO-MPO, MO-V-MPO or a scalarized baseline) from a TOML config.
    Train {
        /// Run config, e.g. configs/mompo/dst.toml.
        #[arg(long, required_unless_present = "resume")]
        config: Option<PathBuf>,
        /// Continue the run in this directory from its latest checkpoint (reads its config.toml).
        #[arg(long)]
        resume: Option<PathBuf>,
        /// Server address host:port (repeatable); overrides the config's servers.
        #[arg(long = "server")]
        servers: Vec<String>,
        /// Override run.total_env_steps.
        #[arg(long)]
        total_env_steps: Option<u64>,
        /// Override any config field, `dotted.path=toml_value` (repeatable), e.g.
        /// `--set seed=3 --set learner.mpo.batch_size=64 --set learner.objectives.1.epsilon=0.0`.
        #[arg(long = "set", value_name = "PATH=VALUE")]
        overrides: Vec<String>,
        /// Override learner.device.
        #[arg(long, value_enum)]
        device: Option<DeviceChoice>,
        /// Every N env steps, write a video of one deterministic episode of the current
        /// policy to <run>/videos/, and one of the final evaluation (videos/final.mp4).
        #[arg(long, value_name = "N")]
        video_every: Option<u64>,
        #[command(flatten)]
        video: VideoArgs,
    },
    /// Train every setting of an ε (or weight) grid, evaluate, and write the Pareto front.
    Sweep {
        /// Sweep file, e.g. configs/sweeps/dst.toml.
        #[arg(long)]
        config: PathBuf,
        /// Server address host:port (repeatable); default: the base config's, or a local server.
        #[arg(long = "server")]
        servers: Vec<String>,
        /// Override learner.device of every run.
        #[arg(long, value_enum)]
        device: Option<DeviceChoice>,
        /// Write a video of every run's final evaluation (<run>/videos/final.mp4).
        #[arg(long)]
        video: bool,
        #[command(flatten)]
        video_args: VideoArgs,
    },
    /// Evaluate a checkpoint with the deterministic policy; returns come from the server.
    Eval {
        /// A run directory (its latest checkpoint) or one checkpoints/step_<n> directory.
        #[arg(long)]
        checkpoint: PathBuf,
        /// Episodes to run.
        #[arg(long, default_value_t = 10)]
        episodes: usize,
        /// Server address host:port (repeatable); default: a local server.
        #[arg(long = "server")]
        servers: Vec<String>,
        /// Write a video of the evaluation here (e.g. out.mp4; .webm and .gif work too):
        /// the instances tiled, each objective's running return under its frame.
        #[arg(long, value_name = "PATH")]
        video: Option<PathBuf>,
        #[command(flatten)]
        video_args: VideoArgs,
    },
    /// List the envs a server offers, with their objectives.
    Envs {
        /// Server address host:port. Omitted: start a local server for the listing.
        #[arg(long)]
        server: Option<String>,
    },
    /// Step envs with uniformly random actions and print per-episode vector returns.
    Demo {
        /// Server address host:port. Omitted: start a local server on 127.0.0.1.
        #[arg(long)]
        server: Option<String>,
        /// Env ids to run, in order.
        #[arg(long = "env", default_values = ["dst", "humanoid-run"])]
        envs: Vec<String>,
        /// Instances per session (B).
        #[arg(long, default_value_t = 4)]
        num_envs: usize,
        /// Episodes to finish per env.
        #[arg(long, default_value_t = 4)]
        episodes: usize,
        /// Seed for the envs and the random actions.
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
}

/// How videos are rendered (with `--video` or `--video-every`).
#[derive(Debug, Clone, Args)]
struct VideoArgs {
    /// Width of each instance's frame in pixels (0 = the server's default, 320).
    #[arg(long, default_value_t = 0)]
    video_width: u32,
    /// Height of each instance's frame in pixels (0 = the server's default, 240).
    #[arg(long, default_value_t = 0)]
    video_height: u32,
    /// Camera the env names ("" = the task's default view).
    #[arg(long, default_value = "")]
    video_camera: String,
    /// Frames per second (default: the task's real time, or 30 when it does not say).
    #[arg(long)]
    video_fps: Option<f64>,
}

impl VideoArgs {
    fn options(&self) -> VideoOptions {
        VideoOptions {
            width: self.video_width,
            height: self.video_height,
            camera: self.video_camera.clone(),
            fps: self.video_fps,
        }
    }
}

fn main() -> Result<()> {
    // Before the runtime's threads exist: mallopt's settings are process-wide.
    agent::device::tune_allocator();
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?
        .block_on(run())
}

async fn run() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Train {
            config,
            resume,
            servers,
            total_env_steps,
            overrides,
            device,
            video_every,
            video,
        } => {
            let path = match (&resume, config) {
                (Some(dir), _) => dir.join("config.toml"),
                (None, Some(path)) => path,
                (None, None) => unreachable!("clap requires --config or --resume"),
            };
            let mut cfg = TrainConfig::load_with(&path, &overrides)
                .with_context(|| format!("loading {}", path.display()))?;
            if let Some(n) = total_env_steps {
                cfg.run.total_env_steps = n;
            }
            if let Some(d) = device {
                cfg.learner.device = d;
            }
            if !servers.is_empty() {
                cfg.env.servers = servers;
            }
            let (addresses, local) = server_addresses(&cfg.env.servers).await?;
            let summary = train(
                cfg,
                &addresses,
                TrainOptions {
                    resume,
                    progress: true,
                    video: video_every.map(|every| VideoPlan {
                        every: Some(every),
                        options: video.options(),
                    }),
                },
            )
            .await;
            if let Some(local) = local {
                local.stop().await?;
            }
            print_summary(&summary?);
        }
        Command::Sweep {
            config,
            servers,
            device,
            video,
            video_args,
        } => {
            let (sweep_cfg, mut base) = SweepConfig::load(&config)
                .with_context(|| format!("loading {}", config.display()))?;
            if let Some(d) = device {
                base.learner.device = d;
            }
            let configured = if servers.is_empty() {
                base.env.servers.clone()
            } else {
                servers
            };
            let (addresses, local) = server_addresses(&configured).await?;
            let options = video.then(|| video_args.options());
            let result = sweep(&sweep_cfg, &base, &addresses, true, options.as_ref()).await;
            if let Some(local) = local {
                local.stop().await?;
            }
            let s = result?;
            let names = s.objectives.join(", ");
            println!(
                "\nsweep {} ({} runs, {:.0} s wall)",
                s.dir.display(),
                s.points.len(),
                s.wall_seconds
            );
            println!(
                "  {:<44} {:>5}  eval return [{names}]  front",
                "setting", "seed"
            );
            for p in &s.points {
                let setting: Vec<String> =
                    p.setting.iter().map(|(k, v)| format!("{k}={v}")).collect();
                let mark = if p.on_front { "*" } else { "" };
                println!(
                    "  {:<44} {:>5}  {:<28} {mark}",
                    setting.join(" "),
                    p.seed,
                    format_vector(&p.eval_return)
                );
            }
            let reference = format_vector(&s.reference_point);
            println!(
                "  hypervolume {:.2} (undiscounted, reference {reference}); EUM {:.3}",
                s.hypervolume, s.expected_utility
            );
            println!(
                "  wrote points.csv front.csv summary.json front.png/svg in {}",
                s.dir.display()
            );
        }
        Command::Eval {
            checkpoint,
            episodes,
            servers,
            video,
            video_args,
        } => {
            let (addresses, local) = server_addresses(&servers).await?;
            let options = video_args.options();
            let video = video.as_deref().map(|path| (path, &options));
            let report = evaluate_checkpoint(&checkpoint, &addresses, episodes, video).await;
            if let Some(local) = local {
                local.stop().await?;
            }
            let r = report?;
            println!(
                "checkpoint {} ({} episodes, deterministic policy)",
                r.checkpoint.display(),
                r.episodes.len()
            );
            println!("  objectives [{}]", r.objectives.join(", "));
            for e in &r.episodes {
                println!(
                    "  env {:>2} length {:>5}  return {}  discounted {}",
                    e.env_index,
                    e.length,
                    format_vector(&e.episode_return),
                    format_vector(&e.discounted_return)
                );
            }
            println!(
                "  mean return {}  mean discounted return (γ={}) {}",
                format_vector(&r.mean_return),
                r.discount,
                format_vector(&r.mean_discounted_return)
            );
            if let Some(v) = &r.video {
                println!("  wrote {} ({} frames)", v.path.display(), v.frames);
            }
        }
        Command::Envs { server } => {
            let (client, local) = connect(server).await?;
            print_envs(&client).await?;
            if let Some(local) = local {
                local.stop().await?;
            }
        }
        Command::Demo {
            server,
            envs,
            num_envs,
            episodes,
            seed,
        } => {
            let (client, local) = connect(server).await?;
            for env_id in &envs {
                demo(&client, env_id, num_envs, episodes, seed).await?;
            }
            if let Some(local) = local {
                local.stop().await?;
            }
        }
    }
    Ok(())
}

/// Connect to `server`, or start a local one when none is given.
async fn connect(server: Option<String>) -> Result<(EnvClient, Option<LocalServer>)> {
    match server {
        Some(address) => Ok((EnvClient::connect(&address).await?, None)),
        None => {
            let local = LocalServer::start(&ServerOptions::default())
                .await
                .context("starting a local env_server")?;
            tracing::info!(address = local.address(), "started local env_server");
            Ok((EnvClient::connect(local.address()).await?, Some(local)))
        }
    }
}

/// The configured servers, or a local one started for this command.
async fn server_addresses(configured: &[String]) -> Result<(Vec<String>, Option<LocalServer>)> {
    if !configured.is_empty() {
        return Ok((configured.to_vec(), None));
    }
    let local = LocalServer::start(&ServerOptions::default())
        .await
        .context("starting a local env_server")?;
    tracing::info!(address = local.address(), "started local env_server");
    Ok((vec![local.address().to_string()], Some(local)))
}

fn print_summary(s: &TrainSummary) {
    let names = s.objectives.join(", ");
    println!("\nrun {}", s.run_dir.display());
    println!(
        "  env steps {}  learner steps {}  episodes {}  wall {:.1} s  learner on {}",
        s.env_steps, s.learner_steps, s.episodes, s.wall_seconds, s.learner_device
    );
    println!("  objectives             [{names}]");
    if let Some(v) = &s.eval_video {
        println!(
            "  evaluation video       {} ({} frames)",
            v.path.display(),
            v.frames
        );
    }
    println!(
        "  recent training return {}",
        format_vector(&s.recent_train_return)
    );
    let eta: Vec<f64> = s.temperature.iter().map(|&t| f64::from(t)).collect();
    println!("  temperatures eta_k     {}", format_vector(&eta));
    println!(
        "  eval return ({} episodes, deterministic policy)",
        s.eval_episodes.len()
    );
    println!("    undiscounted         {}", format_vector(&s.eval_return));
    println!(
        "    discounted (γ={})  {}",
        s.eval_discount,
        format_vector(&s.eval_discounted_return)
    );
    if !s.solve_threshold.is_empty() {
        let rule: Vec<String> = s
            .solve_threshold
            .iter()
            .map(|(k, v)| format!("{k} >= {v}"))
            .collect();
        match &s.solved {
            Some(r) => println!(
                "  solved ({}, mean of {} training episodes) at {} env steps, {:.1} s: {}",
                rule.join(", "),
                agent::solve::SOLVE_WINDOW,
                r.env_steps,
                r.wall_seconds,
                format_vector(&r.running_mean)
            ),
            None => println!(
                "  not solved ({}, mean of {} training episodes)",
                rule.join(", "),
                agent::solve::SOLVE_WINDOW
            ),
        }
    }
    println!(
        "  files: config.toml episodes.csv learner.jsonl summary.json curves.png/svg checkpoints/"
    );
}

async fn print_envs(client: &EnvClient) -> Result<()> {
    let version = client.version().await?;
    println!(
        "env_server {} (protocol {}) at {}",
        version.server_version,
        version.protocol_version,
        client.address()
    );
    for env in client.list_envs().await? {
        println!("\n{:<16} {}", env.env_id, env.description);
        for o in env.objectives {
            println!(
                "    {:<14} [{}, {}]  {}",
                o.name, o.min, o.max, o.description
            );
        }
    }
    Ok(())
}

async fn demo(
    client: &EnvClient,
    env_id: &str,
    num_envs: usize,
    episodes: usize,
    seed: u64,
) -> Result<()> {
    let options = MakeOptions {
        seed: Some(seed),
        ..MakeOptions::new(env_id, num_envs)
    };
    let mut env: RemoteEnv = client
        .make(&options)
        .await
        .with_context(|| format!("making {env_id}"))?;
    let spec = env.spec().clone();
    let names = spec.objective_names().join(", ");
    println!(
        "\n{env_id}: B={num_envs}, objectives [{names}], discount {}",
        spec.discount
    );
    env.reset(&[], &[]).await?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let bar = ProgressBar::new(episodes as u64).with_style(
        ProgressStyle::with_template(
            "{spinner} {msg:>14} episodes {pos}/{len} [{elapsed}] {per_sec}",
        )
        .expect("valid template"),
    );
    bar.set_message(env_id.to_string());
    let started = Instant::now();
    let (mut finished, mut steps) = (Vec::new(), 0u64);
    while finished.len() < episodes {
        let result = env
            .step(&random_action(&spec.action_space, num_envs, &mut rng))
            .await?;
        steps += num_envs as u64;
        for episode in result.episodes {
            bar.inc(1);
            finished.push(episode);
        }
    }
    bar.finish_and_clear();
    let elapsed = started.elapsed().as_secs_f64();
    println!("  episode  env  length  return [{names}]  discounted return");
    for (i, e) in finished.iter().take(episodes).enumerate() {
        println!(
            "  {i:>7}  {:>3}  {:>6}  {:<28}  {}",
            e.env_index,
            e.length,
            format_vector(&e.episode_return),
            format_vector(&e.discounted_return)
        );
    }
    println!(
        "  {steps} env steps in {elapsed:.2} s ({:.0} steps/s)",
        steps as f64 / elapsed
    );
    env.close().await?;
    Ok(())
}

fn format_vector(values: &[f64]) -> String {
    let parts: Vec<String> = values.iter().map(|v| format!("{v:.2}")).collect();
    format!("[{}]", parts.join(", "))
}
