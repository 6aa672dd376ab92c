//! `run.eval_period`: the deterministic policy evaluated while a run trains, as
//! Stable-Baselines3's `EvalCallback` does, into `<run>/eval.csv`, TensorBoard
//! (`eval/periodic_return/<objective>`, conditioned runs `eval/hypervolume`) and the
//! evaluation curve `eval.png` / `eval.svg`.
//!
//! Each time the run's env steps reach a multiple of the period, the schedule's
//! evaluation tap hands over the policy the actors hold at that moment (the one
//! after `EvalPoint::learner_steps` learner steps, the same on every invocation), and
//! a task of the run evaluates it with `run.eval_episodes` episodes on a session of
//! its own, seeded as the final evaluation is (`eval.rs`), so every evaluation of the
//! run starts from the same states. The evaluations read no training random stream
//! and hold nothing the actors or the learner wait for, so turning them on changes
//! no training step; they only take time beside it. An ε-conditioned run evaluates
//! every point of its preference grid and logs the front's hypervolume (and, with
//! `front.discounted_reference_point`, that of its discounted returns).
//!
//! A failed evaluation (its server lost) is logged and skipped; training goes on.
//! On resume, rows after the checkpoint are removed (`resume.rs`) and evaluated
//! again; an evaluation still running when the process died is lost.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;

use tch::Device;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::{TrainError, io};
use crate::core::algo::objectives::LearnerDims;
use crate::core::algo::preferences::PreferenceGrid;
use crate::core::nets::{ActorPolicy, PolicySnapshot};
use crate::env::pool::ServerPool;
use crate::report::metrics::{EVAL_CSV, RunFiles, mean_of};
use crate::report::pareto::hypervolume;
use crate::report::plot::{Figure, Series, SeriesKind};
use crate::report::tensorboard::Scalar;
use crate::runtime::eval::evaluate;
use crate::runtime::run_config::TrainConfig;
use crate::runtime::schedule::{EvalPoint, Schedule};

/// What a run's evaluations need.
pub(super) struct EvalPlan {
    /// The run's config.
    pub cfg: TrainConfig,
    /// Network sizes.
    pub dims: LearnerDims,
    /// The preference grid of an ε-conditioned run.
    pub grid: Option<Arc<PreferenceGrid>>,
    /// Where evaluation sessions are made.
    pub servers: Arc<ServerPool>,
    /// The run's files (TensorBoard scalars).
    pub files: Arc<RunFiles>,
}

/// One evaluation due, with the policy to evaluate.
struct Request {
    point: EvalPoint,
    snapshot: Arc<PolicySnapshot>,
}

/// One evaluated policy (at one grid point for conditioned runs).
struct Evaluated {
    /// The ε of each conditioned objective (empty when not conditioned).
    epsilon: Vec<f64>,
    eval_return: Vec<f64>,
    eval_discounted_return: Vec<f64>,
}

/// Starts the run's evaluations when `run.eval_period` asks for them: the schedule
/// hands each due point, with `params`' policy of that moment, to a task that
/// evaluates them in order. [`finish_evaluations`] waits for it.
pub(super) fn start_evaluations(
    plan: EvalPlan,
    schedule: &Schedule,
    params: watch::Receiver<Arc<PolicySnapshot>>,
) -> Option<JoinHandle<()>> {
    let period = plan.cfg.run.eval_period;
    if period == 0 {
        return None;
    }
    let (tx, mut rx) = mpsc::unbounded_channel::<Request>();
    schedule.set_eval_tap(period, move |point| {
        let snapshot = params.borrow().clone();
        // A closed channel means the evaluations have ended with the run.
        let _ = tx.send(Request { point, snapshot });
    });
    Some(tokio::spawn(async move {
        while let Some(request) = rx.recv().await {
            let at = request.point;
            match evaluate_point(&plan, &request).await {
                Ok(rows) => {
                    if let Err(e) = record(&plan, at, &rows) {
                        tracing::warn!(error = %e, "periodic evaluation: cannot write its results");
                    }
                }
                Err(e) => tracing::warn!(
                    env_steps = at.env_steps,
                    error = %e,
                    "periodic evaluation failed; training goes on"
                ),
            }
        }
    }))
}

/// Ends the evaluations of a run: those already due finish (all of them, unless the
/// run was interrupted, when pending ones are dropped), then the curve is drawn.
pub(super) async fn finish_evaluations(
    task: Option<JoinHandle<()>>,
    schedule: &Schedule,
    interrupted: bool,
    run_dir: &Path,
) -> Result<(), TrainError> {
    let Some(task) = task else {
        return Ok(());
    };
    // Dropping the tap closes the channel: the task ends after the requests queued.
    schedule.clear_eval_tap();
    if interrupted {
        task.abort();
    }
    let _ = task.await;
    plot_evaluations(run_dir)
}

async fn evaluate_point(plan: &EvalPlan, request: &Request) -> Result<Vec<Evaluated>, TrainError> {
    let cfg = &plan.cfg;
    let client = plan.servers.live().await?.client;
    let load = || {
        let mut policy = ActorPolicy::new(&cfg.learner.network, &plan.dims, Device::Cpu);
        policy
            .load(&request.snapshot)
            .map_err(|e| TrainError::Stopped(format!("policy snapshot: {e}")))?;
        Ok::<_, TrainError>(policy)
    };
    let points: Vec<Option<usize>> = match &plan.grid {
        Some(grid) => (0..grid.len()).map(Some).collect(),
        None => vec![None],
    };
    let mut rows = Vec::with_capacity(points.len());
    for g in points {
        let (acting, epsilon) = match (g, &plan.grid) {
            (Some(g), Some(grid)) => (
                load()?.at_preference(&grid.features(g)),
                grid.conditioned_epsilon(g),
            ),
            _ => (load()?, Vec::new()),
        };
        let episodes = evaluate(&client, cfg, acting, cfg.run.eval_episodes).await?;
        rows.push(Evaluated {
            epsilon,
            eval_return: mean_of(episodes.iter().map(|e| &e.episode_return)),
            eval_discounted_return: mean_of(episodes.iter().map(|e| &e.discounted_return)),
        });
    }
    Ok(rows)
}

/// Appends the evaluation's rows to `eval.csv` and its scalars to TensorBoard.
fn record(plan: &EvalPlan, at: EvalPoint, rows: &[Evaluated]) -> Result<(), TrainError> {
    let files = &plan.files;
    let path = files.dir().join(EVAL_CSV);
    let objectives = files.objectives();
    let conditioned: Vec<String> = plan.grid.as_ref().map_or_else(Vec::new, |g| {
        g.conditioned_names()
            .iter()
            .map(|n| format!("epsilon_{n}"))
            .collect()
    });
    let mut file = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(io(&path))?;
    if file.metadata().map_err(io(&path))?.len() == 0 {
        let header: Vec<String> = ["env_steps".to_string(), "learner_steps".into()]
            .into_iter()
            .chain(conditioned)
            .chain(objectives.iter().map(|o| format!("return_{o}")))
            .chain(objectives.iter().map(|o| format!("discounted_return_{o}")))
            .collect();
        writeln!(file, "{}", header.join(",")).map_err(io(&path))?;
    }
    for row in rows {
        let fields: Vec<String> = [at.env_steps.to_string(), at.learner_steps.to_string()]
            .into_iter()
            .chain(row.epsilon.iter().map(f64::to_string))
            .chain(row.eval_return.iter().map(f64::to_string))
            .chain(row.eval_discounted_return.iter().map(f64::to_string))
            .collect();
        writeln!(file, "{}", fields.join(",")).map_err(io(&path))?;
    }
    file.flush().map_err(io(&path))?;
    let scalars = scalars(plan, rows)?;
    files
        .scalars(at.env_steps, &scalars)
        .map_err(io(&files.events_path()))?;
    tracing::info!(env_steps = at.env_steps, scalars = ?scalars.iter().map(|s| (&s.tag, s.value)).collect::<Vec<_>>(), "periodic evaluation");
    Ok(())
}

/// A single policy's mean returns, or a conditioned run's hypervolumes.
fn scalars(plan: &EvalPlan, rows: &[Evaluated]) -> Result<Vec<Scalar>, TrainError> {
    let files = &plan.files;
    let Some(front) = plan.cfg.front.as_ref().filter(|_| plan.grid.is_some()) else {
        let mut out = files.per_objective("eval/periodic_return", &rows[0].eval_return);
        out.extend(files.per_objective(
            "eval/periodic_discounted_return",
            &rows[0].eval_discounted_return,
        ));
        return Ok(out);
    };
    let objectives = files.objectives();
    let returns: Vec<Vec<f64>> = rows.iter().map(|r| r.eval_return.clone()).collect();
    let mut out = vec![Scalar::new(
        "eval/hypervolume",
        hypervolume(&returns, &front.reference(objectives)?),
    )];
    if let Some(reference) = front.discounted_reference(objectives)? {
        let discounted: Vec<Vec<f64>> = rows
            .iter()
            .map(|r| r.eval_discounted_return.clone())
            .collect();
        out.push(Scalar::new(
            "eval/discounted_hypervolume",
            hypervolume(&discounted, &reference),
        ));
    }
    Ok(out)
}

/// `eval.png` / `eval.svg`: each objective's evaluation return against env steps (a
/// conditioned run: each grid point's, one line per objective and point).
fn plot_evaluations(run_dir: &Path) -> Result<(), TrainError> {
    let path = run_dir.join(EVAL_CSV);
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(()); // no evaluation fell due
    };
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let rows: Vec<Vec<&str>> = lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|r| r.len() == header.len())
        .collect();
    let epsilon: Vec<usize> = (0..header.len())
        .filter(|&i| header[i].starts_with("epsilon_"))
        .collect();
    let mut series: Vec<Series> = Vec::new();
    for (col, name) in header.iter().enumerate() {
        let Some(objective) = name.strip_prefix("return_") else {
            continue;
        };
        for row in &rows {
            let at: Vec<&str> = epsilon.iter().map(|&i| row[i]).collect();
            let label = match at.is_empty() {
                true => objective.to_string(),
                false => format!("{objective} at ε {}", at.join("/")),
            };
            let point = (
                row[0].parse().unwrap_or(f64::NAN),
                row[col].parse().unwrap_or(f64::NAN),
            );
            match series.iter_mut().find(|s| s.label == label) {
                Some(s) => s.points.push(point),
                None => series.push(Series {
                    label,
                    points: vec![point],
                    kind: SeriesKind::Line,
                }),
            }
        }
    }
    if series.iter().all(|s| s.points.is_empty()) {
        return Ok(());
    }
    let figure = Figure {
        title: format!(
            "evaluation returns, deterministic policy ({})",
            run_dir
                .file_name()
                .map(|n| n.to_string_lossy())
                .unwrap_or_default()
        ),
        x_label: "env steps".into(),
        y_label: "mean episode return".into(),
        series,
        log_x: false,
    };
    crate::report::plot::save(&figure, &run_dir.join("eval"))?;
    Ok(())
}
