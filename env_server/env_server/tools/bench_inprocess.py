"""In-process throughput of a Session: the server's per-Step work minus gRPC.

    python -m env_server.tools.bench_inprocess --env humanoid-run --num-envs 8 --steps 2000 --seed 0

Runs `--steps` batch Steps of `--num-envs` instances through Session.step (the same
validation, autoreset and episode accounting the server runs, fed the same raw bytes a
StepRequest carries) with uniform-random actions generated up front, and prints ONE
JSON line: {"env", "num_envs", "steps", "env_steps_per_s", "call_p50_ms", "call_p99_ms"}.
env_steps_per_s = steps * num_envs / total seconds. The Rust bench compares it with the
same steps through the server.

With --raw the loop calls the B Task instances directly (no validation, autoreset or
accounting): what a Python user stepping local envs gets, the strictest baseline.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import gymnasium
import numpy as np

from env_server.construction import make_session
from env_server.registry import Registry


def random_actions(space: gymnasium.spaces.Space, steps: int, num_envs: int, seed: int) -> np.ndarray:
    """[steps, num_envs, ...] uniform actions in the space's bounds, in its wire dtype."""
    rng = np.random.default_rng(seed)
    if isinstance(space, gymnasium.spaces.Discrete):
        return rng.integers(space.start, space.start + space.n, size=(steps, num_envs), dtype=np.int64)
    low = np.where(np.isfinite(space.low), space.low, -1.0)
    high = np.where(np.isfinite(space.high), space.high, 1.0)
    return rng.uniform(low, high, size=(steps, num_envs, *space.shape)).astype(space.dtype)


def run(env_id: str, num_envs: int, steps: int, seed: int, raw: bool = False) -> dict[str, object]:
    session = make_session(Registry().resolve(env_id), num_envs, {}, seed=seed)
    try:
        session.reset()
        actions = random_actions(session.spec.action_space, steps, num_envs, seed)
        dtype = session.validator.dtype.name
        shape = list(session.validator.shape)
        payloads = [a.tobytes() for a in actions]
        times = np.empty(steps, np.float64)
        clock = time.perf_counter
        if raw:
            tasks = session.tasks
            start = clock()
            for t in range(steps):
                t0 = clock()
                for task, action in zip(tasks, actions[t]):
                    if task.step(action).terminated:
                        task.reset()
                times[t] = clock() - t0
        else:
            start = clock()
            for t, data in enumerate(payloads):
                t0 = clock()
                session.step(dtype, shape, data)
                times[t] = clock() - t0
        total = clock() - start
    finally:
        session.close()
    return {
        "env": env_id,
        "mode": "raw" if raw else "session",
        "num_envs": num_envs,
        "steps": steps,
        "env_steps_per_s": round(steps * num_envs / total, 1),
        "call_p50_ms": round(float(np.percentile(times, 50)) * 1e3, 4),
        "call_p99_ms": round(float(np.percentile(times, 99)) * 1e3, 4),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m env_server.tools.bench_inprocess", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="humanoid-run", help="env id (default humanoid-run)")
    p.add_argument("--num-envs", type=int, default=8, help="instances per Step (default 8)")
    p.add_argument("--steps", type=int, default=2000, help="batch Steps to time (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed for the session and the actions (default 0)")
    p.add_argument("--raw", action="store_true", help="step the Task instances directly (no Session)")
    args = p.parse_args(argv)
    print(json.dumps(run(args.env, args.num_envs, args.steps, args.seed, args.raw)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
