//! `agent sweep`: train every setting of a grid and write its front; finish a stopped
//! sweep (`--resume`), run one shard (`--shard`), or merge shards (`--report`).

use std::path::PathBuf;

use agent::sweep::{Shard, SweepConfig, SweepFolder};
use anyhow::{Context, Result};

use super::args::{RunArgs, VideoArgs};
use super::servers::{server_addresses, stop};

/// `agent sweep`'s flags.
#[derive(Debug, clap::Args)]
pub(crate) struct SweepArgs {
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
    shard: Option<Shard>,
    /// Write the front of these sweep folders (a sweep, or every shard of one, each
    /// job once) from their finished runs; no training, no server.
    #[arg(long, value_name = "DIR", num_args = 1.., conflicts_with_all = ["servers", "overrides", "total_env_steps", "device", "video"])]
    report: Vec<PathBuf>,
    /// The sweep's folder (default: a new runs/sweep__<name>__<time>/); with --report,
    /// where the merged front goes (default: the folder itself when one is given, else
    /// a new sweep__<name>__<time>/ beside the first).
    #[arg(long, value_name = "DIR")]
    dir: Option<PathBuf>,
    #[command(flatten)]
    run: RunArgs,
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
}

impl SweepArgs {
    pub(crate) async fn run(self) -> Result<()> {
        if !self.report.is_empty() {
            let s = agent::sweep::report(&self.report, self.dir.as_deref())?;
            super::report::sweep(&s);
            return Ok(());
        }
        let folder = self.folder()?;
        let configured = if self.run.servers.is_empty() {
            folder.base.env.servers.clone()
        } else {
            self.run.servers
        };
        let (addresses, local) = server_addresses(&configured, &folder.base.env.connection).await?;
        let options = self.video.then(|| self.video_args.options());
        let result = agent::sweep::run(&folder, &addresses, true, options.as_ref()).await;
        stop(local).await?;
        super::report::sweep(&result?);
        Ok(())
    }

    /// The sweep's folder, created or reopened, with what may differ between
    /// invocations of one sweep (see `SweepFolder::comparable`) taken from the flags.
    fn folder(&self) -> Result<SweepFolder> {
        let mut folder = match (&self.resume, &self.config) {
            (Some(dir), _) => {
                SweepFolder::open(dir).with_context(|| format!("--resume {}", dir.display()))?
            }
            (None, Some(config)) => {
                let (mut sweep_cfg, base) = SweepConfig::load_with(config, &self.run.overrides)
                    .with_context(|| format!("loading {}", config.display()))?;
                if self.run.total_env_steps.is_some() {
                    sweep_cfg.total_env_steps = self.run.total_env_steps;
                }
                base.validate()?;
                SweepFolder::create(&sweep_cfg, &base, self.shard, self.dir.as_deref())?
            }
            (None, None) => unreachable!("clap requires --config, --resume or --report"),
        };
        if let Some(d) = self.run.device {
            folder.base.learner.device = d;
        }
        if let Some(n) = self.population {
            folder.sweep.population = Some(n as usize);
        }
        folder.base.env.connection = self
            .run
            .connection
            .clone()
            .apply(folder.base.env.connection);
        folder.base.validate()?;
        Ok(folder)
    }
}
