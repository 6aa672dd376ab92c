//! `agent`: command-line entry point (the only place that uses `anyhow`).
#![allow(clippy::print_stdout, reason = "a CLI prints its results")]

mod cli;

use std::path::PathBuf;

use agent::core::learner_config::DeviceChoice;
use agent::env::connection::ConnectionConfig;
use agent::report::video::VideoPlan;
use agent::runtime::eval::evaluate_checkpoint_at;
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train};
use agent::sweep::{SweepConfig, SweepFolder};
use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use cli::args::{ConnectionArgs, VideoArgs, server_address};
use cli::servers::{connect, server_addresses};

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
        /// Server address (repeatable): host:port, https://host:port, dns:NAME:PORT
        /// (every address of NAME), dns://NAMESERVER/NAME:PORT or file:PATH (one address
        /// per line, re-read when a server is lost); overrides the config's servers.
        #[arg(long = "server", value_name = "ADDRESS", value_parser = server_address)]
        servers: Vec<String>,
        #[command(flatten)]
        connection: ConnectionArgs,
        /// Override run.total_env_steps.
        #[arg(long)]
        total_env_steps: Option<u64>,
        /// Override any config field, `dotted.path=toml_value` (repeatable), e.g.
        /// `--set seed=3 --set learner.mpo.batch_size=64 --set learner.objectives.1.epsilon=0.0`.
        /// With --resume only the budget, periods, checkpoint_replay, eval_episodes,
        /// servers and device may change (an error names any other field).
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
    ///
    /// `--resume DIR` finishes a stopped sweep (finished runs are kept, the others continue
    /// from their checkpoints); `--shard I/N` runs the jobs j with j mod N = I; `--report
    /// DIR...` merges shard folders into the front of the whole sweep.
    Sweep {
        /// Sweep file, e.g. configs/sweeps/dst.toml.
        #[arg(long, required_unless_present_any = ["resume", "report"], conflicts_with_all = ["resume", "report"])]
        config: Option<PathBuf>,
        /// Finish the sweep (or shard) in this folder: keep its finished runs, continue the
        /// others from their checkpoints, then write its front (reads the folder's
        /// sweep.toml, base.toml and sweep.json).
        #[arg(long, value_name = "DIR", conflicts_with_all = ["report", "shard", "overrides", "total_env_steps", "dir"])]
        resume: Option<PathBuf>,
        /// Run one slice of the sweep: the jobs j (settings x seeds, in order) with
        /// j mod N = I, in a folder of its own; `--report` merges the N folders.
        #[arg(long, value_name = "I/N", conflicts_with = "report")]
        shard: Option<agent::sweep::Shard>,
        /// Write the front of these sweep folders (a sweep, or every shard of one, each
        /// job once) from their finished runs; no training, no server.
        #[arg(long, value_name = "DIR", num_args = 1.., conflicts_with_all = ["servers", "overrides", "total_env_steps", "device", "video"])]
        report: Vec<PathBuf>,
        /// The sweep's folder (default: a new runs/sweep__<name>__<time>/); with --report,
        /// where the merged front goes (default: the folder itself when one is given, else
        /// a new sweep__<name>__<time>/ beside the first).
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
        /// Server address (repeatable): host:port, https://host:port, dns:NAME:PORT,
        /// dns://NAMESERVER/NAME:PORT or file:PATH; default: the base config's, or a
        /// local server.
        #[arg(long = "server", value_name = "ADDRESS", value_parser = server_address)]
        servers: Vec<String>,
        #[command(flatten)]
        connection: ConnectionArgs,
        /// Override the sweep file's total_env_steps (every run's run.total_env_steps).
        #[arg(long)]
        total_env_steps: Option<u64>,
        /// Override any field of the base config, `dotted.path=toml_value` (repeatable),
        /// as `train --set`; applied after the sweep file's `set`, before the grid.
        #[arg(long = "set", value_name = "PATH=VALUE")]
        overrides: Vec<String>,
        /// Override learner.device of every run.
        #[arg(long, value_enum)]
        device: Option<DeviceChoice>,
        /// Most members of one population (overrides the sweep file's `population`):
        /// jobs that differ only in seed, ε or weights train as one batched learner;
        /// 1 trains every job alone.
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
        population: Option<u64>,
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
        /// Server address (repeatable): host:port, https://host:port, dns:NAME:PORT,
        /// dns://NAMESERVER/NAME:PORT or file:PATH (the first address found is used);
        /// default: a local server.
        #[arg(long = "server", value_name = "ADDRESS", value_parser = server_address)]
        servers: Vec<String>,
        /// How to reach --server (the run's own env.connection is not used).
        #[command(flatten)]
        connection: ConnectionArgs,
        /// Write a video of the evaluation here (e.g. out.mp4; .webm and .gif work too):
        /// the instances tiled, each objective's running return under its frame.
        #[arg(long, value_name = "PATH")]
        video: Option<PathBuf>,
        #[command(flatten)]
        video_args: VideoArgs,
        /// An ε-conditioned policy's preference, e.g. `task=0.1,action_norm=0.02`:
        /// conditioned objectives only, any ε > 0 (on its training grid or not);
        /// default: the grid's middle point.
        #[arg(long, value_name = "NAME=EPS,...", value_parser = agent::core::algo::preferences::parse_setting)]
        epsilon: Option<std::collections::BTreeMap<String, f64>>,
    },
    /// Write a checkpoint's deterministic actions for the observations in a file.
    ///
    /// To check another implementation of the policy (e.g. env_server.trained_policy)
    /// against the agent's. Observations: rows of the flattened observation, [B, obs_dim], as .npy or JSON
    /// (`[[0.1, 2.0], ...]`). Actions: what the agent sends the env, the Gaussian's mean
    /// clipped to [-1, 1] and mapped onto the Box bounds ([B, D] float32), or the most
    /// likely index ([B] int64).
    Act {
        /// A run directory (its latest checkpoint) or one checkpoints/step_<n> directory.
        #[arg(long)]
        checkpoint: PathBuf,
        /// The observations, a .npy or .json file.
        #[arg(long, value_name = "FILE")]
        observations: PathBuf,
        /// Write the actions here (.npy or .json); default: print them as JSON.
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
        /// An ε-conditioned policy's preference, as for `eval --epsilon`; the
        /// observations are then the env's, without the preference features.
        #[arg(long, value_name = "NAME=EPS,...", value_parser = agent::core::algo::preferences::parse_setting)]
        epsilon: Option<std::collections::BTreeMap<String, f64>>,
    },
    /// List the envs a server offers, with their objectives.
    Envs {
        /// Server address host:port, https://host:port, dns:NAME:PORT or
        /// file:PATH (its first server). Omitted: start a local server
        /// for the listing.
        #[arg(long, value_name = "ADDRESS", value_parser = server_address)]
        server: Option<String>,
        #[command(flatten)]
        connection: ConnectionArgs,
    },
    /// Step envs with uniformly random actions and print per-episode vector returns.
    Demo {
        /// Server address host:port, https://host:port, dns:NAME:PORT or
        /// file:PATH (its first server). Omitted: start a local server
        /// on 127.0.0.1.
        #[arg(long, value_name = "ADDRESS", value_parser = server_address)]
        server: Option<String>,
        #[command(flatten)]
        connection: ConnectionArgs,
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

fn main() -> Result<()> {
    // Before the runtime's threads exist: mallopt's settings are process-wide.
    agent::core::device::tune_allocator();
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
            connection,
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
            cfg.env.connection = connection.apply(cfg.env.connection);
            cfg.validate()?;
            if resume.is_some() {
                let stored = TrainConfig::load(&path)
                    .with_context(|| format!("loading {}", path.display()))?;
                cfg.check_resume_changes(&stored)
                    .context("--resume continues the run as configured")?;
            }
            let (addresses, local) =
                server_addresses(&cfg.env.servers, &cfg.env.connection).await?;
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
            let summary = summary?;
            cli::report::train(&summary);
            if summary.interrupted.is_some() {
                // The shell's convention for a job ended by SIGINT.
                std::process::exit(130);
            }
        }
        Command::Sweep {
            config,
            resume,
            shard,
            report,
            dir,
            servers,
            connection,
            total_env_steps,
            overrides,
            device,
            population,
            video,
            video_args,
        } => {
            if !report.is_empty() {
                let s = agent::sweep::report(&report, dir.as_deref())?;
                cli::report::sweep(&s);
                return Ok(());
            }
            let mut folder = match (&resume, config) {
                (Some(dir), _) => {
                    SweepFolder::open(dir).with_context(|| format!("--resume {}", dir.display()))?
                }
                (None, Some(config)) => {
                    let (mut sweep_cfg, base) = SweepConfig::load_with(&config, &overrides)
                        .with_context(|| format!("loading {}", config.display()))?;
                    if total_env_steps.is_some() {
                        sweep_cfg.total_env_steps = total_env_steps;
                    }
                    base.validate()?;
                    SweepFolder::create(&sweep_cfg, &base, shard, dir.as_deref())?
                }
                (None, None) => unreachable!("clap requires --config, --resume or --report"),
            };
            // What may differ between invocations of one sweep (see SweepFolder::comparable).
            if let Some(d) = device {
                folder.base.learner.device = d;
            }
            if let Some(n) = population {
                folder.sweep.population = Some(n as usize);
            }
            let configured = if servers.is_empty() {
                folder.base.env.servers.clone()
            } else {
                servers
            };
            folder.base.env.connection = connection.apply(folder.base.env.connection);
            folder.base.validate()?;
            let (addresses, local) =
                server_addresses(&configured, &folder.base.env.connection).await?;
            let options = video.then(|| video_args.options());
            let result = agent::sweep::run(&folder, &addresses, true, options.as_ref()).await;
            if let Some(local) = local {
                local.stop().await?;
            }
            let s = result?;
            cli::report::sweep(&s);
        }
        Command::Eval {
            checkpoint,
            episodes,
            servers,
            connection,
            video,
            video_args,
            epsilon,
        } => {
            let connection = connection.apply(ConnectionConfig::default());
            connection.validate()?;
            let (addresses, local) = server_addresses(&servers, &connection).await?;
            let options = video_args.options();
            let video = video.as_deref().map(|path| (path, &options));
            let report = evaluate_checkpoint_at(
                &checkpoint,
                epsilon.as_ref(),
                &addresses,
                &connection,
                episodes,
                video,
            )
            .await;
            if let Some(local) = local {
                local.stop().await?;
            }
            let r = report?;
            cli::report::eval(&r);
        }
        Command::Act {
            checkpoint,
            observations,
            out,
            epsilon,
        } => {
            if let Some(json) = agent::runtime::act::act_on_file(
                &checkpoint,
                &observations,
                out.as_deref(),
                epsilon.as_ref(),
            )? {
                println!("{json}");
            }
        }
        Command::Envs { server, connection } => {
            let (client, local) = connect(server, connection).await?;
            cli::demo::list_envs(&client).await?;
            if let Some(local) = local {
                local.stop().await?;
            }
        }
        Command::Demo {
            server,
            connection,
            envs,
            num_envs,
            episodes,
            seed,
        } => {
            let (client, local) = connect(server, connection).await?;
            for env_id in &envs {
                cli::demo::run(&client, env_id, num_envs, episodes, seed).await?;
            }
            if let Some(local) = local {
                local.stop().await?;
            }
        }
    }
    Ok(())
}
