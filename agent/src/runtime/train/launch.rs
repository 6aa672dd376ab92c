//! A population's actors and learner, from their start to their end: the learner's OS
//! thread, the actors (tokio tasks), periodic videos and the progress display, and how
//! they all stop (the budget spent, a signal, or the first error).

use indicatif::ProgressBar;
use tokio::task::JoinHandle;

use super::actors::spawn_actors;
use super::open::OpenedLearner;
use super::progress::{progress_bar, spawn_ticker};
use super::videos::{PeriodicContext, record_periodically};
use super::{Population, TrainError, TrainOptions, io};
use crate::core::algo::preferences::PreferenceGrid;
use crate::core::nets::PolicySnapshot;
use crate::runtime::learner::{
    LearnerContext, LearnerDone, LearnerLoopError, LoopPeriods, run_learner,
};

/// A started population's threads and tasks.
pub(super) struct Running {
    learner: std::thread::JoinHandle<Result<LearnerDone, LearnerLoopError>>,
    actors: Vec<JoinHandle<()>>,
    videos: Option<JoinHandle<()>>,
    bars: Vec<ProgressBar>,
    tickers: Vec<JoinHandle<()>>,
}

impl Population {
    /// Starts the learner thread, the actors, periodic videos and the progress display.
    pub(super) fn start(
        &self,
        opened: OpenedLearner,
        options: &TrainOptions,
    ) -> Result<Running, TrainError> {
        let ctx = LearnerContext {
            learner: opened.learner,
            members: opened.members,
            periods: LoopPeriods {
                publish: self.cfg.run.publish_period,
                checkpoint: self.cfg.run.checkpoint_period,
                log: self.cfg.run.log_period,
            },
        };
        let learner = std::thread::Builder::new()
            .name("learner".into())
            .spawn(move || run_learner(ctx))
            .map_err(io(&self.runs[0].run_dir))?;
        let actors = spawn_actors(self, &self.stop_all())?;
        let videos = self.start_videos(options);
        let mut bars = Vec::new();
        let mut tickers = Vec::new();
        for run in &self.runs {
            let shown = options.progress && self.runs.len() == 1;
            let bar = progress_bar(shown, &self.cfg, &run.schedule);
            tickers.push(spawn_ticker(
                run.schedule.clone(),
                run.latest.clone(),
                bar.clone(),
                self.objectives.clone(),
                self.learner_objectives.len(),
            ));
            bars.push(bar);
        }
        Ok(Running {
            learner,
            actors,
            videos,
            bars,
            tickers,
        })
    }

    /// Periodic videos, which follow a single run's policy.
    fn start_videos(&self, options: &TrainOptions) -> Option<JoinHandle<()>> {
        let plan = options.video.as_ref().filter(|_| self.runs.len() == 1)?;
        let every = plan.every?;
        let run = &self.runs[0];
        let ctx = PeriodicContext {
            client: self.servers.first().client,
            cfg: self.cfg.clone(),
            dims: self.dims.clone(),
            preference: self.grid.as_deref().map(PreferenceGrid::default_features),
            params: run.params.clone(),
            schedule: run.schedule.clone(),
            dir: run.run_dir.join("videos"),
        };
        Some(tokio::spawn(record_periodically(
            ctx,
            every,
            plan.options.clone(),
        )))
    }

    /// Waits for every actor, then stops the rest and joins the learner; its members'
    /// final policies, in member order. A run an actor or the learner stopped with an
    /// error returns that error (the learner wrote a final checkpoint of every member).
    pub(super) async fn wait(&self, running: Running) -> Result<Vec<PolicySnapshot>, TrainError> {
        let stop_all = self.stop_all();
        for actor in running.actors {
            // The task itself catches panics; a join error is a cancelled runtime.
            if let Err(e) = actor.await {
                stop_all(Some(format!("an actor task ended abnormally: {e}")));
            }
        }
        stop_all(None);
        for ticker in running.tickers {
            ticker.abort();
        }
        if let Some(videos) = running.videos {
            videos.abort(); // a video in progress is cut short (its file may be incomplete)
        }
        let learner = running.learner;
        let done = tokio::task::spawn_blocking(move || learner.join())
            .await
            .map_err(|e| TrainError::Stopped(e.to_string()))?
            .map_err(|_| TrainError::Stopped("the learner thread panicked".into()))?;
        for bar in running.bars {
            bar.finish_and_clear();
        }
        if let Some(error) = self.runs.iter().find_map(|r| r.schedule.counters().error) {
            return Err(TrainError::Stopped(error));
        }
        let LearnerDone { learner, policies } = done?;
        drop(learner);
        Ok(policies)
    }

    /// Stops every member's schedule, with `reason` when it is an error.
    fn stop_all(&self) -> impl Fn(Option<String>) + Clone + Send + 'static {
        let schedules: Vec<_> = self.runs.iter().map(|r| r.schedule.clone()).collect();
        move |reason: Option<String>| {
            for s in &schedules {
                s.stop(reason.clone());
            }
        }
    }
}
