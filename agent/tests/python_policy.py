"""The Python side of agent/tests/python_policy.rs: a run's policy through
env_server.trained_policy, on the observations the agent acted on and on RemoteEnv.

    python_policy.py [--epsilon NAME=EPS,...] RUN OBSERVATIONS ACTIONS [ADDRESS ENV_ID EPISODES SEED NUM_ENVS]

OBSERVATIONS and ACTIONS are the files given to and written by `agent act` (.npy or
.json). Prints JSON: `max_abs_diff`, the largest difference between the agent's actions
and `policy.act(obs)` (deterministic), and `episodes`, what `trained_policy.evaluate`
reports for EPISODES episodes on NUM_ENVS instances of ENV_ID seeded from SEED (none
without an ADDRESS). `--epsilon` loads an ε-conditioned policy at that preference, as
`agent act --epsilon` and `agent eval --epsilon` take it.
"""

from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

from env_server.trained_policy import evaluate, load_policy


def _read(path: pathlib.Path) -> np.ndarray:
    return np.load(path) if path.suffix == ".npy" else np.array(json.loads(path.read_text()))


def main() -> None:
    args = sys.argv[1:]
    epsilon = None
    if args[0] == "--epsilon":
        epsilon = {name: float(v) for name, v in (item.split("=") for item in args[1].split(","))}
        args = args[2:]
    run, observations, actions, *server = args
    run_dir = pathlib.Path(run)
    policy = load_policy(run_dir, epsilon)
    ours = policy.act(_read(pathlib.Path(observations))).numpy()
    theirs = _read(pathlib.Path(actions))
    if ours.shape != theirs.shape:
        raise SystemExit(f"actions: expected the agent's shape {list(theirs.shape)}, got {list(ours.shape)}")
    done = []
    if server:
        address, env_id, *counts = server
        episodes, seed, num_envs = (int(v) for v in counts)
        done = evaluate(policy, address, env_id, episodes, seed=seed, num_envs=num_envs)
    report = {
        "max_abs_diff": float(np.max(np.abs(ours.astype(np.float64) - theirs.astype(np.float64)))),
        "episodes": [
            {"env_index": e["env_index"], "length": e["length"], "episode_return": e["episode_return"].tolist()}
            for e in done
        ],
    }
    print(json.dumps(report))


if __name__ == "__main__":
    main()
