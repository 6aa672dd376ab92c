//! Opening a population: the servers and the env's spec, the learner's dimensions and
//! device, the members' run folders (new, or one reopened to resume) and, per member,
//! its files, schedule, published policy and periodic evaluations, with its side of
//! the learner loop.

use std::sync::{Arc, Mutex};

use tokio::sync::watch;

use super::evals::{EvalPlan, start_evaluations};
use super::setup::{Opened, OpenedRun, open_population, schedule_for, snippet_layout};
use super::{MemberRun, Population, TrainError, TrainOptions, io};
use crate::core::algo::Learner;
use crate::core::algo::objectives::{LearnerDims, check_declared};
use crate::core::device::{choose_device, configure_threads};
use crate::env::pool::ServerPool;
use crate::report::metrics::RunFiles;
use crate::runtime::env_setup::probe_spec;
use crate::runtime::learner::MemberLoop;
use crate::runtime::resume::Checkpointer;
use crate::runtime::run_config::TrainConfig;

/// An opened population's learner, with each member's side of the learner loop.
pub(super) struct OpenedLearner {
    pub learner: Learner,
    pub members: Vec<MemberLoop>,
}

/// A population opened and not yet started.
pub(super) struct Opening {
    pub population: Population,
    pub learner: OpenedLearner,
}

/// One member's run and its side of the learner loop.
struct OpenedMember {
    run: MemberRun,
    member: MemberLoop,
}

impl Population {
    /// Connects to the servers, probes the env, and opens every member's run.
    pub(super) async fn open(
        cfgs: Vec<TrainConfig>,
        addresses: &[String],
        options: &TrainOptions,
    ) -> Result<Opening, TrainError> {
        let cfg = cfgs[0].clone();
        configure_threads(cfg.learner.num_threads);
        let servers = Arc::new(
            ServerPool::connect_with(addresses, &cfg.env.connection, cfg.env.deadlines).await?,
        );
        let probe = &cfg;
        let spec = servers
            .on_live("spec probe", |client| async move {
                probe_spec(&client, probe).await
            })
            .await?;
        let dims = LearnerDims::from_spec(&spec)?
            .with_preference_features(cfg.learner.preference_features());
        for c in &cfgs {
            check_declared(&c.learner, &spec.objectives)?;
        }
        let objectives: Vec<String> = spec.objectives.iter().map(|o| o.name.clone()).collect();
        let device = choose_device(&cfg.learner, &dims, cfgs.len())?;
        let Opened { runs, learner } =
            open_population(&cfgs, options.resume.as_deref(), &dims, device)?;
        let mut population = Population {
            grid: learner.preference_grid().cloned().map(Arc::new),
            layout: snippet_layout(&cfg, &dims, objectives.len()),
            cfg,
            servers,
            objectives,
            learner_objectives: learner.objectives().names(),
            discount: spec.discount,
            dims,
            device,
            runs: Vec::with_capacity(cfgs.len()),
        };
        let mut members = Vec::with_capacity(cfgs.len());
        for (p, (member_cfg, opened)) in cfgs.into_iter().zip(runs).enumerate() {
            let opened = population.open_member(p, member_cfg, opened, &learner)?;
            population.runs.push(opened.run);
            members.push(opened.member);
        }
        Ok(Opening {
            population,
            learner: OpenedLearner { learner, members },
        })
    }

    /// Member `p`'s run (files, schedule, published policy, periodic evaluations) and
    /// its side of the learner loop.
    fn open_member(
        &self,
        p: usize,
        cfg: TrainConfig,
        opened: OpenedRun,
        learner: &Learner,
    ) -> Result<OpenedMember, TrainError> {
        let OpenedRun {
            run_dir,
            counters,
            resumed,
        } = opened;
        let conditioned: Vec<String> = self.grid.as_ref().map_or_else(Vec::new, |g| {
            g.conditioned_names()
                .into_iter()
                .map(String::from)
                .collect()
        });
        let files = Arc::new(
            RunFiles::open(&run_dir, &self.objectives, &conditioned).map_err(io(&run_dir))?,
        );
        let first_acts: Vec<u64> = counters.actors.iter().map(|a| a.acts).collect();
        let schedule = Arc::new(schedule_for(
            &cfg,
            self.layout,
            &self.objectives,
            counters,
            &run_dir,
            resumed.as_ref(),
        )?);
        let segments_end = resumed
            .as_ref()
            .and_then(|r| r.replay.as_ref())
            .map_or(0, |r| r.inserted);
        let (params_tx, params_rx) = watch::channel(Arc::new(learner.member_policy_snapshot(p)));
        let latest = Arc::new(Mutex::new(None));
        let plan = EvalPlan {
            cfg: cfg.clone(),
            dims: self.dims.clone(),
            grid: self.grid.clone(),
            servers: self.servers.clone(),
            files: files.clone(),
        };
        let evaluations = start_evaluations(plan, &schedule, params_rx.clone());
        let member = MemberLoop {
            schedule: schedule.clone(),
            params: params_tx,
            files: files.clone(),
            latest: latest.clone(),
            checkpointer: Checkpointer::new(files.clone(), cfg.run.checkpoint_replay, segments_end)
                .for_member(p),
        };
        let run = MemberRun {
            cfg,
            run_dir,
            files,
            schedule,
            params: params_rx,
            latest,
            first_acts,
            evaluations,
        };
        Ok(OpenedMember { run, member })
    }
}
