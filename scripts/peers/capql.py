#!/usr/bin/env python3
"""MORL-Baselines' CAPQL on a two-objective MO-Gymnasium MuJoCo task, run as its benchmark does.

    .venv-peers/bin/python scripts/peers/capql.py --task mo-halfcheetah-v5 --seed 0 \
        --steps 200000 --results docs/benchmarks/mujoco-results.csv --session ID

As MORL-Baselines' experiments/benchmark/launch_experiment.py: seed_everything(seed), the
training env wrapped in MORecordEpisodeStatistics(gamma=0.99), a separate evaluation env,
CAPQL(env, gamma=0.99, log=True, seed) with its defaults (SAC-like, (256, 256) networks,
lr 3e-4, batch 128, tau 0.005, alpha 0.2, learning_starts 1000) and CAPQL.train(). Its own
loop evaluates every `eval_freq` env steps: for each of `num_eval_weights_for_front`
weights (equally_spaced_weights) the deterministic policy's mean vector return over
`num_eval_episodes_for_front` episodes, discounted with gamma, and logs the hypervolume
of that front. That evaluation runs only when `log` is on, so wandb stays on in
"disabled" mode (nothing is sent or written), and this script wraps the two functions
capql.py imports, policy_evaluation_mo and log_all_multi_policy_metrics, to keep each
front, undiscounted and discounted, as rows of the results file. MORL-Baselines'
defaults are 100 weights x 5 episodes every 10k steps; ours (11 x 4 every 20k, the
issue's peer figures) cost less evaluation, and are options. Our 2-D hypervolume is
checked against MORL-Baselines' (pymoo) on every front.
"""

from __future__ import annotations

import argparse
import math
import time

import mo_gymnasium as mo_gym
import morl_baselines
import numpy as np
import results
import torch
from mo_gymnasium.wrappers import MORecordEpisodeStatistics
from morl_baselines.common.evaluation import seed_everything
from morl_baselines.common.pareto import filter_pareto_dominated
from morl_baselines.common.performance_indicators import hypervolume
from morl_baselines.common.weights import equally_spaced_weights
from morl_baselines.multi_policy.capql import capql


class OfflineCAPQL(capql.CAPQL):
    """CAPQL whose wandb run is created in "disabled" mode: its evaluation code runs, nothing is logged."""

    def setup_wandb(self, project_name, experiment_name, entity=None, group=None, mode=None) -> None:
        super().setup_wandb(project_name, experiment_name, entity, group, mode="disabled")


class FrontRecorder:
    """Wraps capql's evaluation functions; one (env steps, front, discounted front, wall, eval s) per evaluation."""

    def __init__(self, clock: results.Clock) -> None:
        self.clock = clock
        self.pending: list[tuple] = []
        self.started: float | None = None
        self.fronts: list[tuple[int, list, list, float, float]] = []
        self.evaluate = capql.policy_evaluation_mo
        self.log = capql.log_all_multi_policy_metrics
        capql.policy_evaluation_mo = self.policy_evaluation_mo
        capql.log_all_multi_policy_metrics = self.log_all_multi_policy_metrics

    def policy_evaluation_mo(self, *args, **kwargs):
        if self.started is None:
            self.started = time.perf_counter()
        out = self.evaluate(*args, **kwargs)
        self.pending.append(out)
        return out

    def log_all_multi_policy_metrics(self, current_front, hv_ref_point, reward_dim, global_step, **kwargs):
        discounted = [tuple(float(v) for v in p[3]) for p in self.pending]
        if discounted != [tuple(float(v) for v in p) for p in current_front]:
            raise RuntimeError("capql.py's front is not the evaluations this script recorded")
        self.close(global_step, hv_ref_point)
        self.log(current_front, hv_ref_point, reward_dim, global_step, **kwargs)

    def close(self, env_steps: int, ref: np.ndarray) -> None:
        """Ends one evaluation: keeps its fronts and checks our hypervolume against MORL-Baselines'."""
        front = [tuple(float(v) for v in p[2]) for p in self.pending]
        discounted = [tuple(float(v) for v in p[3]) for p in self.pending]
        theirs = hypervolume(ref, list(filter_pareto_dominated(np.array(discounted))))
        ours = results.hypervolume(discounted, tuple(ref))
        if not math.isclose(theirs, ours, rel_tol=1e-9, abs_tol=1e-6):
            raise RuntimeError(f"hypervolume: MORL-Baselines {theirs} != ours {ours} on {discounted}")
        self.clock.eval_s += time.perf_counter() - self.started
        self.fronts.append((env_steps, front, discounted, self.clock.wall(), self.clock.eval_s))
        self.pending, self.started = [], None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eval-weights", type=int, default=11, help="num_eval_weights_for_front")
    ap.add_argument("--eval-episodes", type=int, default=4, help="num_eval_episodes_for_front")
    args = results.parse_run_args(ap, sorted(results.REFERENCES), steps=200_000, eval_every=20_000)

    torch.set_num_threads(args.threads)
    clock = results.Clock()
    seed_everything(args.seed)
    env = MORecordEpisodeStatistics(mo_gym.make(args.task), gamma=results.GAMMA)
    env.reset(seed=args.seed)
    env.action_space.seed(args.seed)
    eval_env = mo_gym.make(args.task)
    eval_env.reset(seed=args.seed + 1000)
    ref = np.array(results.REFERENCES[args.task]["discounted"])
    recorder = FrontRecorder(clock)
    agent = OfflineCAPQL(env, gamma=results.GAMMA, log=True, seed=args.seed, device="cpu")
    agent.train(
        total_timesteps=args.steps,
        eval_env=eval_env,
        ref_point=ref,
        num_eval_weights_for_front=args.eval_weights,
        num_eval_episodes_for_front=args.eval_episodes,
        eval_freq=args.eval_every or args.steps + 1,
    )
    if not recorder.fronts or recorder.fronts[-1][0] != agent.global_step:
        for w in equally_spaced_weights(agent.reward_dim, n=args.eval_weights):
            capql.policy_evaluation_mo(agent, eval_env, w, rep=args.eval_episodes)
        recorder.close(agent.global_step, ref)

    settings = (
        f"morl-baselines {morl_baselines.__version__} CAPQL defaults, gamma={results.GAMMA}; eval "
        f"{args.eval_weights} weights x {args.eval_episodes} episodes deterministic every {args.eval_every}; "
        f"threads={args.threads}"
    )

    def row(kind, steps, front, discounted, wall, ev):
        fields = {"front": front, "front_discounted": discounted, "wall_s": wall, "eval_s": ev}
        return results.row(args.task, "CAPQL", args.seed, kind, steps, settings=settings, **fields)

    rows = [row("eval", *f) for f in recorder.fronts]
    rows.append(row("final", *recorder.fronts[-1][:3], clock.wall(), clock.eval_s))
    results.append(args.results, rows, args.session)
    last = rows[-1]
    print(
        f"CAPQL {args.task} seed {args.seed}: HV discounted {last['hv_discounted']} at {last['ref_discounted']}, "
        f"undiscounted {last['hv_undiscounted']} at {last['ref_undiscounted']}, {clock.wall():.0f} s"
    )


if __name__ == "__main__":
    main()
