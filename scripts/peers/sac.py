#!/usr/bin/env python3
"""Stable-Baselines3 SAC on a Gymnasium MuJoCo task, evaluated as SB3's EvalCallback does.

    .venv-peers/bin/python scripts/peers/sac.py --task HalfCheetah-v5 --seed 0 \
        --steps 100000 --results docs/benchmarks/mujoco-results.csv --session ID

SAC with SB3 2.9.2's defaults (MlpPolicy (256, 256), batch 256, lr 3e-4, tau 0.005, one
gradient step per env step, automatic entropy) except `learning_starts` = 10000, as the
RL Zoo runs HalfCheetah and Hopper. Every `--eval-every` env steps an EvalCallback runs
the deterministic policy for `--eval-episodes` episodes on its own env (seeded with
seed + 1000); each evaluation becomes a row of the results file, and the end of the run
a final row (the evaluation at the last step, run once more if no periodic one fell
there). Rows are appended only when the run finishes.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import results
import stable_baselines3
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv


class TimedEval(EvalCallback):
    """EvalCallback that also records (env steps, mean return, wall, eval seconds)."""

    def __init__(self, clock: results.Clock, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.clock = clock
        self.points: list[tuple[int, float, float, float]] = []

    def _on_step(self) -> bool:
        due = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
        started = time.perf_counter()
        go = super()._on_step()
        if due:
            self.clock.eval_s += time.perf_counter() - started
            self.points.append((self.num_timesteps, self.last_mean_reward, self.clock.wall(), self.clock.eval_s))
        return go


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eval-episodes", type=int, default=10)
    ap.add_argument("--learning-starts", type=int, default=10_000)
    args = results.parse_run_args(ap, None, steps=100_000, eval_every=10_000)

    torch.set_num_threads(args.threads)
    clock = results.Clock()
    eval_env = DummyVecEnv([lambda: Monitor(gym.make(args.task))])
    eval_env.seed(args.seed + 1000)
    model = SAC("MlpPolicy", gym.make(args.task), learning_starts=args.learning_starts, seed=args.seed, device="cpu")
    callback = TimedEval(
        clock, eval_env, n_eval_episodes=args.eval_episodes, eval_freq=args.eval_every, deterministic=True, verbose=0
    )
    model.learn(total_timesteps=args.steps, callback=callback)
    if not callback.points or callback.points[-1][0] != model.num_timesteps:
        started = time.perf_counter()
        mean, _ = evaluate_policy(model, eval_env, n_eval_episodes=args.eval_episodes, deterministic=True)
        clock.eval_s += time.perf_counter() - started
        callback.points.append((model.num_timesteps, float(mean), clock.wall(), clock.eval_s))

    settings = (
        f"stable-baselines3 {stable_baselines3.__version__} SAC defaults, learning_starts={args.learning_starts}; "
        f"eval {args.eval_episodes} episodes deterministic every {args.eval_every}; threads={args.threads}"
    )
    rows = [
        results.row(args.task, "SAC", args.seed, "eval", steps, return_=ret, wall_s=wall, eval_s=ev, settings=settings)
        for steps, ret, wall, ev in callback.points
    ]
    steps, ret, _, _ = callback.points[-1]
    final = {"return_": ret, "wall_s": clock.wall(), "eval_s": clock.eval_s, "settings": settings}
    rows.append(results.row(args.task, "SAC", args.seed, "final", steps, **final))
    results.append(args.results, rows, args.session)
    print(f"SAC {args.task} seed {args.seed}: return {ret:.1f} at {steps} env steps, {clock.wall():.0f} s")


if __name__ == "__main__":
    main()
