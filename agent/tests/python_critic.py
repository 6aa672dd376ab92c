"""The Python side of agent/tests/python_policy.rs's critic check: scripts/probe_critic.py's
transcription of the Q critics against the agent's own values.

    python_critic.py CHECKPOINT OBS ACTIONS Q

OBS, ACTIONS and Q are .npy files the test writes: observations [N, O] (an
ε-conditioned learner's preference features appended), actions [M, N, D] and the
agent's `Learner::q_values` of them [M, N, C]. Prints JSON: `max_abs_diff` and `max_relative_diff` (each
difference over max(1, the largest |q| of its critic head), `head_scale`) between `q`
and probe_critic's `Critic` on the same inputs, from CHECKPOINT's params.safetensors
and state.json.
"""

from __future__ import annotations

import importlib.util
import json
import pathlib
import sys

import numpy as np
import torch
from safetensors.torch import load_file

SCRIPT = pathlib.Path(__file__).resolve().parents[2] / "scripts" / "probe_critic.py"


def _probe_critic():
    spec = importlib.util.spec_from_file_location("probe_critic", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main() -> None:
    checkpoint, *inputs = (pathlib.Path(a) for a in sys.argv[1:5])
    network = json.loads((checkpoint / "state.json").read_text())["config"]["network"]
    critic = _probe_critic().Critic(load_file(checkpoint / "params.safetensors"), network)
    obs, actions, ours = (torch.from_numpy(np.load(path)) for path in inputs)
    with torch.no_grad():
        theirs = critic(obs, actions)
    if theirs.shape != ours.shape:
        raise SystemExit(f"q: expected the agent's shape {list(ours.shape)}, got {list(theirs.shape)}")
    diff = (theirs - ours).abs()
    # Float32 rounding in the layers' sums is relative to the size of the values summed,
    # not to each result: a Q near 0 made of terms near 100 carries their rounding.
    head_scale = ours.abs().amax(dim=(0, 1)).clamp(min=1.0)  # [C]
    print(
        json.dumps(
            {
                "max_abs_diff": diff.max().item(),
                "max_relative_diff": (diff / head_scale).max().item(),
                "head_scale": head_scale.tolist(),
            }
        )
    )


if __name__ == "__main__":
    main()
