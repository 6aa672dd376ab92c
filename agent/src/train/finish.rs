//! The end of a run: the final evaluation of the deterministic policy (recorded to
//! `videos/final.mp4` when videos were asked for), then the reports a finished or
//! interrupted run leaves: evaluation scalars, `summary.json` and the curves.

use std::path::Path;

use super::curves::plot_curves;
use super::{TrainError, TrainSummary, io};
use crate::env::EpisodeSummary;
use crate::env::pool::ServerPool;
use crate::eval::{evaluate, evaluate_recorded};
use crate::metrics::{RunFiles, write_json_atomic};
use crate::nets::ActorPolicy;
use crate::run_config::TrainConfig;
use crate::video::{VideoPlan, VideoReport};

/// What the final evaluation produced.
pub(super) struct FinalEvaluation {
    /// The episodes, as the server reported them (none for an interrupted run).
    pub episodes: Vec<EpisodeSummary>,
    /// Their video, when videos were asked for.
    pub video: Option<VideoReport>,
}

/// The evaluation episodes, on a live server; none when the run was interrupted, since
/// whoever stopped it wants it to end soon.
pub(super) async fn final_evaluation(
    cfg: &TrainConfig,
    servers: &ServerPool,
    policy: ActorPolicy,
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
    let client = servers.live().await?.client;
    let episodes = cfg.run.eval_episodes;
    Ok(match video {
        Some(plan) => {
            let path = run_dir.join("videos").join("final.mp4");
            let (episodes, video) =
                evaluate_recorded(&client, cfg, policy, episodes, &path, &plan.options).await?;
            FinalEvaluation {
                episodes,
                video: Some(video),
            }
        }
        None => FinalEvaluation {
            episodes: evaluate(&client, cfg, policy, episodes).await?,
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
