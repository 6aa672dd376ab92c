//! `agent train`: one run from a run config, or the rest of a stopped one (`--resume`).

use std::path::PathBuf;

use agent::report::video::VideoPlan;
use agent::runtime::run_config::TrainConfig;
use agent::runtime::train::{TrainOptions, train};
use anyhow::{Context, Result};

use super::args::{RunArgs, VideoArgs};
use super::servers::{server_addresses, stop};

/// `agent train`'s flags.
#[derive(Debug, clap::Args)]
pub(crate) struct TrainArgs {
    /// Run config, e.g. configs/mompo/dst.toml.
    #[arg(long, required_unless_present = "resume")]
    config: Option<PathBuf>,
    /// Continue the run in this directory from its latest checkpoint (reads its config.toml).
    #[arg(long)]
    resume: Option<PathBuf>,
    #[command(flatten)]
    run: RunArgs,
    /// Every N env steps, write a video of one deterministic episode of the current
    /// policy to <run>/videos/, and one of the final evaluation (videos/final.mp4).
    #[arg(long, value_name = "N")]
    video_every: Option<u64>,
    #[command(flatten)]
    video: VideoArgs,
}

impl TrainArgs {
    pub(crate) async fn run(self) -> Result<()> {
        let cfg = self.config()?;
        let (addresses, local) = server_addresses(&cfg.env.servers, &cfg.env.connection).await?;
        let options = TrainOptions {
            resume: self.resume,
            progress: true,
            video: self.video_every.map(|every| VideoPlan {
                every: Some(every),
                options: self.video.options(),
            }),
        };
        let summary = train(cfg, &addresses, options).await;
        stop(local).await?;
        let summary = summary?;
        super::report::train(&summary);
        if summary.interrupted.is_some() {
            // The shell's convention for a job ended by SIGINT.
            std::process::exit(130);
        }
        Ok(())
    }

    /// The run config with the flags applied, validated; with `--resume`, also checked
    /// against the stored one for changes a resume cannot take.
    fn config(&self) -> Result<TrainConfig> {
        let path = match (&self.resume, &self.config) {
            (Some(dir), _) => dir.join("config.toml"),
            (None, Some(path)) => path.clone(),
            (None, None) => unreachable!("clap requires --config or --resume"),
        };
        let loading = || format!("loading {}", path.display());
        let mut cfg = TrainConfig::load_with(&path, &self.run.overrides).with_context(loading)?;
        if let Some(n) = self.run.total_env_steps {
            cfg.run.total_env_steps = n;
        }
        if let Some(d) = self.run.device {
            cfg.learner.device = d;
        }
        if !self.run.servers.is_empty() {
            cfg.env.servers = self.run.servers.clone();
        }
        cfg.env.connection = self.run.connection.clone().apply(cfg.env.connection);
        cfg.validate()?;
        if self.resume.is_some() {
            let stored = TrainConfig::load(&path).with_context(loading)?;
            cfg.check_resume_changes(&stored)
                .context("--resume continues the run as configured")?;
        }
        Ok(cfg)
    }
}
