//! The command line: one module per subcommand (its flags and what it does), the flags
//! several share, where servers come from, and what it prints. Binary-only: the library
//! (`agent::*`) returns results and never prints.

pub(crate) mod args;
pub(crate) mod demo;
pub(crate) mod eval;
pub(crate) mod report;
pub(crate) mod servers;
pub(crate) mod sweep;
pub(crate) mod train;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Multi-objective MPO agents for env_server environments.
#[derive(Debug, Parser)]
#[command(version, about)]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Command,
}

#[derive(Debug, Subcommand)]
pub(crate) enum Command {
    /// Train one agent (MO-MPO, MO-V-MPO or a scalarized baseline) from a TOML config.
    Train(train::TrainArgs),
    /// Train every setting of an ε (or weight) grid, evaluate, and write the Pareto front.
    ///
    /// `--resume DIR` finishes a stopped sweep (finished runs are kept, the others continue
    /// from their checkpoints); `--shard I/N` runs the jobs j with j mod N = I; `--report
    /// DIR...` merges shard folders into the front of the whole sweep.
    Sweep(sweep::SweepArgs),
    /// Evaluate a checkpoint with the deterministic policy; returns come from the server.
    Eval(eval::EvalArgs),
    /// Write a checkpoint's deterministic actions for the observations in a file.
    ///
    /// To check another implementation of the policy (e.g. env_server.trained_policy)
    /// against the agent's. Observations: rows of the flattened observation, [B, obs_dim], as .npy or JSON
    /// (`[[0.1, 2.0], ...]`). Actions: what the agent sends the env, the Gaussian's mean
    /// clipped to [-1, 1] and mapped onto the Box bounds ([B, D] float32), or the most
    /// likely index ([B] int64).
    Act(eval::ActArgs),
    /// List the envs a server offers, with their objectives.
    Envs(demo::EnvsArgs),
    /// Step envs with uniformly random actions and print per-episode vector returns.
    Demo(demo::DemoArgs),
}

impl Command {
    pub(crate) async fn run(self) -> Result<()> {
        match self {
            Command::Train(args) => args.run().await,
            Command::Sweep(args) => args.run().await,
            Command::Eval(args) => args.run().await,
            Command::Act(args) => args.run(),
            Command::Envs(args) => args.run().await,
            Command::Demo(args) => args.run().await,
        }
    }
}
