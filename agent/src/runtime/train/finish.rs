//! The end of a run: the final evaluation of the deterministic policy (recorded to
//! `videos/final.mp4` when videos were asked for), then the reports a finished or
//! interrupted run leaves: evaluation scalars, `summary.json` and the curves.

use std::path::Path;

use tch::Device;

use super::curves::plot_curves;
use super::evals::finish_evaluations;
use super::{MemberRun, Population, TrainError, TrainOptions, TrainSummary, front, io};
use crate::core::nets::ActorPolicy;
use crate::core::nets::PolicySnapshot;
use crate::env::EpisodeSummary;
use crate::env::error::EnvError;
use crate::env::pool::ServerPool;
use crate::report::metrics::mean_of;
use crate::report::metrics::{RunFiles, write_json_atomic};
use crate::report::video::{VideoPlan, VideoReport};
use crate::runtime::eval::{evaluate, evaluate_recorded};
use crate::runtime::run_config::TrainConfig;

/// What the final evaluation produced.
pub(super) struct FinalEvaluation {
    /// The episodes, as the server reported them (none for an interrupted run).
    pub episodes: Vec<EpisodeSummary>,
    /// Their video, when videos were asked for.
    pub video: Option<VideoReport>,
}

/// The evaluation episodes of the policy `policy` makes, on a live server; none when
/// the run was interrupted, since whoever stopped it wants it to end soon. Without a
/// video, an evaluation whose session is lost (a fault between agent and server) is
/// made again from its first episode, with the same seeds.
pub(super) async fn final_evaluation(
    cfg: &TrainConfig,
    servers: &ServerPool,
    policy: &(dyn Fn() -> Result<ActorPolicy, EnvError> + Sync),
    interrupted: bool,
    video: Option<&VideoPlan>,
    run_dir: &Path,
) -> Result<FinalEvaluation, TrainError> {
    if interrupted {
        return Ok(FinalEvaluation {
            episodes: Vec::new(),
            video: None,
        });
    }
    let episodes = cfg.run.eval_episodes;
    Ok(match video {
        Some(plan) => {
            let client = servers.live().await?.client;
            let path = run_dir.join("videos").join("final.mp4");
            let (episodes, video) =
                evaluate_recorded(&client, cfg, policy()?, episodes, &path, &plan.options).await?;
            FinalEvaluation {
                episodes,
                video: Some(video),
            }
        }
        None => FinalEvaluation {
            episodes: servers
                .on_live("final evaluation", |client| {
                    let policy = policy();
                    async move { evaluate(&client, cfg, policy?, episodes).await }
                })
                .await?,
            video: None,
        },
    })
}

/// Evaluation scalars (when there was an evaluation), the flushed metric files,
/// `summary.json` and the learning curves.
pub(super) fn write_reports(summary: &TrainSummary, files: &RunFiles) -> Result<(), TrainError> {
    let run_dir = &summary.run_dir;
    if !summary.eval_episodes.is_empty() {
        let mut scalars = files.per_objective("eval/return", &summary.eval_return);
        scalars
            .extend(files.per_objective("eval/discounted_return", &summary.eval_discounted_return));
        files
            .scalars(summary.env_steps, &scalars)
            .map_err(io(run_dir))?;
    }
    files.flush().map_err(io(run_dir))?;
    write_json_atomic(&run_dir.join("summary.json"), summary).map_err(io(run_dir))?;
    plot_curves(run_dir, &summary.objectives)?;
    Ok(())
}

impl Population {
    /// Waits for the members' periodic evaluations, then evaluates each member's final
    /// policy and writes its reports; summaries in member order.
    pub(super) async fn finish(
        &mut self,
        policies: Vec<PolicySnapshot>,
        options: &TrainOptions,
    ) -> Result<Vec<TrainSummary>, TrainError> {
        for run in &mut self.runs {
            let interrupted = run.schedule.counters().interrupted.is_some();
            let task = run.evaluations.take();
            finish_evaluations(task, &run.schedule, interrupted, &run.run_dir).await?;
        }
        let mut summaries = Vec::with_capacity(self.runs.len());
        for (run, snapshot) in self.runs.iter().zip(policies) {
            summaries.push(self.finish_member(run, &snapshot, options).await?);
        }
        Ok(summaries)
    }

    /// A member's final evaluation (its own policy), conditioned front and reports.
    async fn finish_member(
        &self,
        run: &MemberRun,
        snapshot: &PolicySnapshot,
        options: &TrainOptions,
    ) -> Result<TrainSummary, TrainError> {
        let cfg = &run.cfg;
        let counters = run.schedule.counters();
        let servers = &self.servers;
        let dims = &self.dims;
        let grid = self.grid.as_deref();
        let policy = || {
            let mut policy = ActorPolicy::new(&cfg.learner.network, dims, Device::Cpu);
            policy
                .load(snapshot)
                .map_err(|e| EnvError::Process(format!("policy snapshot: {e}")))?;
            Ok(match grid {
                Some(grid) => policy.at_preference(&grid.default_features()),
                None => policy,
            })
        };
        let FinalEvaluation {
            episodes: eval,
            video: eval_video,
        } = final_evaluation(
            cfg,
            servers,
            &policy,
            counters.interrupted.is_some(),
            options.video.as_ref(),
            &run.run_dir,
        )
        .await?;
        let front = match grid {
            Some(grid) if counters.interrupted.is_none() => Some(
                front::conditioned_front(
                    cfg,
                    servers,
                    grid,
                    dims,
                    snapshot,
                    self.objectives.clone(),
                    &run.run_dir,
                )
                .await?,
            ),
            _ => None,
        };
        let stats = run.latest.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let summary = TrainSummary {
            run_dir: run.run_dir.clone(),
            objectives: self.objectives.clone(),
            env_steps: counters.env_steps,
            learner_steps: counters.learner_steps,
            episodes: counters.episodes,
            wall_seconds: run.schedule.elapsed_seconds(),
            recent_train_return: counters.recent_mean_return(),
            temperature: stats.map(|s| s.temperature).unwrap_or_default(),
            learner_objectives: self.learner_objectives.clone(),
            eval_return: mean_of(eval.iter().map(|e| &e.episode_return)),
            eval_discounted_return: mean_of(eval.iter().map(|e| &e.discounted_return)),
            eval_discount: self.discount,
            eval_episodes: eval,
            learner_device: format!("{:?}", self.device),
            solve_threshold: cfg.run.solve_threshold.clone(),
            solved: run.schedule.solved(),
            interrupted: counters.interrupted.clone(),
            eval_video,
            actor_servers: servers.actor_servers(),
            env_faults: servers.faults(),
            front,
        };
        write_reports(&summary, &run.files)?;
        Ok(summary)
    }
}
