//! What `agent train`, `sweep` and `eval` print when they finish (the library returns
//! the summaries; only the binary prints them).

use agent::report::metrics::{format_temperatures, format_value, format_vector};
use agent::runtime::eval::EvalReport;
use agent::runtime::train::TrainSummary;
use agent::sweep::{FrontSummary, setting_label};

/// `agent train`'s closing summary.
pub(crate) fn train(s: &TrainSummary) {
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
    println!(
        "  temperatures eta_k     {}",
        format_temperatures(&s.temperature, s.learner_objectives.len())
    );
    if let Some(signal) = &s.interrupted {
        println!(
            "  interrupted by {signal}: no evaluation; continue with `agent train --resume {}`",
            s.run_dir.display()
        );
    }
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
                agent::runtime::solve::SOLVE_WINDOW,
                r.env_steps,
                r.wall_seconds,
                format_vector(&r.running_mean)
            ),
            None => println!(
                "  not solved ({}, mean of {} training episodes)",
                rule.join(", "),
                agent::runtime::solve::SOLVE_WINDOW
            ),
        }
    }
    // replay/ holds the checkpoints' replay segments (none with checkpoint_replay = false).
    let replay = if s.run_dir.join("replay").exists() {
        " replay/"
    } else {
        ""
    };
    println!(
        "  files: config.toml episodes.csv learner.jsonl summary.json curves.png/svg events.out.tfevents.* checkpoints/{replay}"
    );
    if let Some(front) = &s.front {
        front_table(front, "front", "grid points");
    }
}

/// `agent sweep`'s table: every run, the spread across seeds, and the hypervolumes.
pub(crate) fn sweep(s: &FrontSummary) {
    front_table(s, "sweep", "runs");
}

/// A front's table (a sweep's `what` = "sweep" of runs, an ε-conditioned run's
/// "front" of grid points): every point, the spread across seeds, the hypervolumes.
fn front_table(s: &FrontSummary, what: &str, points: &str) {
    let names = s.objectives.join(", ");
    println!(
        "\n{what} {} ({} {points}, {:.0} s wall)",
        s.dir.display(),
        s.points.len(),
        s.wall_seconds
    );
    println!(
        "  {:<44} {:>5}  eval return [{names}]  front",
        "setting", "seed"
    );
    for p in &s.points {
        let mark = if p.on_front { "*" } else { "" };
        println!(
            "  {:<44} {:>5}  {:<28} {mark}",
            setting_label(&p.setting),
            p.seed,
            format_vector(&p.eval_return)
        );
    }
    if s.seed_fronts.len() > 1 {
        println!("  across seeds: median [min .. max] per objective");
        for spread in &s.settings {
            let cells: Vec<String> = (0..spread.median.len())
                .map(|i| {
                    format!(
                        "{} [{} .. {}]",
                        format_value(spread.median[i]),
                        format_value(spread.min[i]),
                        format_value(spread.max[i])
                    )
                })
                .collect();
            println!(
                "  {:<44} {:>5}  {}",
                setting_label(&spread.setting),
                format!("x{}", spread.seeds),
                cells.join("  ")
            );
        }
        let hv: Vec<f64> = s.seed_fronts.iter().map(|f| f.hypervolume).collect();
        let each: Vec<String> = s
            .seed_fronts
            .iter()
            .map(|f| format!("seed {} {:.2}", f.seed, f.hypervolume))
            .collect();
        println!(
            "  hypervolume per seed: {}; median {:.2}, range [{:.2} .. {:.2}]",
            each.join(", "),
            agent::sweep::seeds::median(&hv),
            hv.iter().copied().fold(f64::INFINITY, f64::min),
            hv.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        );
    }
    let reference = format_vector(&s.reference_point);
    println!(
        "  hypervolume {:.2} (all {points}; undiscounted, reference {reference}); EUM {:.3}",
        s.hypervolume, s.expected_utility
    );
    if let (Some(best), Some(igd)) = (s.true_hypervolume, s.igd) {
        println!(
            "  true front: hypervolume {best:.2} ({:.0}% reached); IGD {igd:.3}",
            100.0 * s.hypervolume / best
        );
    }
    println!(
        "  wrote points.csv front.csv summary.json front.png/svg in {}",
        s.dir.display()
    );
}

/// `agent eval`'s per-episode returns and their means.
pub(crate) fn eval(r: &EvalReport) {
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
