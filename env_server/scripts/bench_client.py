"""The Python client's B = 1 round trip: RemoteEnv.step against a local gymnasium step.

    ../.venv/bin/python scripts/bench_client.py --steps 2000 --rounds 10
    ../.venv/bin/python scripts/bench_client.py --server-args "--front grpcio"

Starts `python -m env_server --port 0` on 127.0.0.1 with --server-args (default none:
the front a user gets, native when built), then alternates, --rounds times, --steps
RemoteEnv("pendulum").step calls and as many local gymnasium Pendulum-v1 steps, both
with the same uniform-random actions, resetting when an episode ends. Alternating keeps
both measured in the same phase of a shared machine. Prints ONE JSON line:
{"front", "remote_step_ms", "local_step_ms", "ratio", "rounds", "steps"}, each ms figure
the median over rounds of the per-round mean, and ratio the median of per-round ratios.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from collections.abc import Callable

import gymnasium
import numpy as np

from env_server.client import RemoteEnv
from env_server.server import resolve_front


def per_step_ms(env: gymnasium.Env, actions: np.ndarray) -> float:
    step: Callable = env.step
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = step(action)
        if terminated or truncated:
            env.reset()
    return (time.perf_counter() - start) / len(actions) * 1e3


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=2000, help="steps per round and side")
    p.add_argument("--rounds", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--server-args", default="", help='flags for the server, e.g. "--front grpcio"')
    args = p.parse_args()
    server_args = shlex.split(args.server_args)
    front = "auto"
    if "--front" in server_args:
        front = server_args[server_args.index("--front") + 1]
    server = subprocess.Popen(
        [sys.executable, "-m", "env_server", "--port", "0", *server_args],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        line = server.stdout.readline()
        if not line.startswith("LISTENING "):
            raise SystemExit(f"bench_client: the server did not report LISTENING, it printed {line!r}")
        remote = RemoteEnv(line.split()[1], "pendulum", seed=args.seed)
        local = gymnasium.make("Pendulum-v1")
        remote.reset(seed=args.seed)
        local.reset(seed=args.seed)
        actions = np.random.default_rng(args.seed).uniform(-2, 2, (args.steps, 1)).astype(np.float32)
        per_step_ms(remote, actions[:200])  # warm up the stream and both envs
        per_step_ms(local, actions[:200])
        remote_ms, local_ms = [], []
        for _ in range(args.rounds):
            remote_ms.append(per_step_ms(remote, actions))
            local_ms.append(per_step_ms(local, actions))
        remote.close()
    finally:
        server.terminate()
        server.wait(10)
    ratios = np.array(remote_ms) / np.array(local_ms)
    print(
        json.dumps(
            {
                "front": resolve_front(front),
                "remote_step_ms": round(float(np.median(remote_ms)), 4),
                "local_step_ms": round(float(np.median(local_ms)), 4),
                "ratio": round(float(np.median(ratios)), 1),
                "rounds": args.rounds,
                "steps": args.steps,
            }
        )
    )


if __name__ == "__main__":
    main()
