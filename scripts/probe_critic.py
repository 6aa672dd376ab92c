#!/usr/bin/env python3
"""What a checkpoint's critics say along its own deterministic policy, per preference.

    .venv/bin/python scripts/probe_critic.py RUN_OR_CHECKPOINT_DIR \
        [--epsilon objective_1=0.001] [--epsilon objective_1=1] [--steps 1000] [--samples 20]

For an MO-Gymnasium or gymnasium task (`env.id = "mo:..."` or `"gym:..."` in the run's
config.toml; a gym: task's one objective is its reward) it rolls the deterministic
policy out in-process for --steps steps (seed 1), then, at the first half of those
states, prints per learned objective (critic head):

- `Q(mu)`: the critic's mean Q at the policy's mean action, beside `G`: the realised
  discounted return-to-go from those states (the checkpoint's γ; each sees at least
  --steps / 2 more steps). Q is the value of the stochastic policy the learner trains,
  G that of the deterministic one, so they differ by what the exploration noise costs;
- `sd_M`: the standard deviation of Q over --samples actions drawn from the policy,
  averaged over states: what the E-step has to tell actions apart with;
- `eta*`: the temperature that meets this objective's ε on these states (eq. 34's dual,
  minimised here) beside `eta`, the checkpoint's, which the learner fitted on replayed
  states (its training episodes), not on the deterministic policy's;
- `tilt`: how far the E-step's weights move the sample mean, in standard deviations
  (the norm over action dims of sum_i w_i z_i with z the centred standardised samples).

Below each, per action dimension, what the E-step's weights ask of the Gaussian: the
weighted variance of the standardised samples (1: keep sigma, below 1: narrow it) and
the mean's move, |sum_i w_i z_i| in standard deviations, both averaged over states. With
the default --samples 20 these are noisy; --samples 200 resolves a few tenths.

Above these, the policy's standard deviation over those states and action dims (its
median and 10%-90% range) and the median |mean action|: how much exploration noise the
stochastic policy that the critics value carries beside the deterministic one.

Each `--epsilon` is a preference of an ε-conditioned run (default: its grid's middle
point); a fixed-ε run takes none. The critic is transcribed from
agent/src/core/nets/critic/mod.rs (shared first layer `W_obs obs + W_act tanh(a) + b` ->
LayerNorm -> tanh, further shared layers with ELU, per-objective heads Linear -> ELU ->
Linear; with `critic_preference = "every_layer"` the preference features also enter
every layer after the first) and reads `critic/critic.*` of params.safetensors; mlp
policies with continuous actions only. agent/tests/python_policy.rs checks that this
transcription gives the agent's own Q (`Learner::q_values`) on trained checkpoints.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import re
import sys

import numpy as np
import torch
from safetensors.torch import load_file

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "env_server"))
from env_server.trained_policy import checkpoint_dir, grid_points, load_policy  # noqa: E402


def run_dir(ckpt: pathlib.Path) -> pathlib.Path:
    return ckpt.parent.parent if ckpt.parent.name == "checkpoints" else ckpt


class Critic:
    """The learner's C critic heads: `(obs [N, O], actions [M, N, D]) -> Q [M, N, C]`."""

    def __init__(self, params: dict[str, torch.Tensor], network: dict) -> None:
        def get(name: str) -> torch.Tensor:
            return params[f"critic/critic.{name}"]

        self.obs_w, self.obs_b = get("shared.obs.weight"), get("shared.obs.bias")
        self.act_w = get("shared.action.weight")
        self.norm = (get("shared.layer_norm.weight"), get("shared.layer_norm.bias"))
        self.tanh_action = bool(network["tanh_on_critic_action"])
        shared = network.get("critic_shared_layers", 1)
        self.shared = [(get(f"shared.linear_{i}.weight"), get(f"shared.linear_{i}.bias")) for i in range(1, shared)]
        heads = len(network["critic_layers"]) - shared + 1
        self.heads = [(get(f"heads.linear_{i}.weight"), get(f"heads.linear_{i}.bias")) for i in range(heads)]
        # `critic_preference = "every_layer"`: the last head's input is wider than the
        # last hidden size by the carried preference features.
        self.carry = self.heads[-1][0].shape[1] - network["critic_layers"][-1]

    def __call__(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        a = torch.tanh(actions) if self.tanh_action else actions
        h = obs @ self.obs_w.T + self.obs_b + a @ self.act_w.T
        h = torch.tanh(torch.nn.functional.layer_norm(h, (h.shape[-1],), *self.norm, 1e-5))
        carried = obs[:, obs.shape[1] - self.carry :]  # [N, F]

        def carry(x: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
            """x [.., R, w] with the carried rows [R, F] appended (x when none)."""
            return torch.cat([x, rows.expand(*x.shape[:-2], *rows.shape)], -1) if self.carry else x

        for w, b in self.shared:
            h = torch.nn.functional.elu(carry(h, carried) @ w.T + b)
        h = carry(h, carried)
        m, n, width = h.shape
        x = h.reshape(1, m * n, width).expand(self.heads[0][0].shape[0], -1, -1)  # [C, M N, w]
        rows = carried.expand(m, -1, -1).reshape(m * n, self.carry)
        for i, (w, b) in enumerate(self.heads):
            x = torch.baddbmm(b, carry(x, rows) if i > 0 else x, w)
            if i + 1 < len(self.heads):
                x = torch.nn.functional.elu(x)
        return x[..., 0].reshape(-1, m, n).permute(1, 2, 0)


def solved_temperature(q: torch.Tensor, epsilon: float) -> float:
    """argmin over η of η ε + η mean_n log mean_m exp(q / η) for q [M, N] (eq. 34),
    by golden-section search on log η."""

    def dual(log_eta: float) -> float:
        eta = math.exp(log_eta)
        return eta * epsilon + eta * (torch.logsumexp(q / eta, 0) - math.log(q.shape[0])).mean().item()

    lo, hi, r = -10.0, 10.0, (math.sqrt(5) - 1) / 2
    for _ in range(80):
        a, b = hi - r * (hi - lo), lo + r * (hi - lo)
        lo, hi = (lo, b) if dual(a) < dual(b) else (a, hi)
    return math.exp((lo + hi) / 2)


def make_env(env_id: str):
    """The task of a run's `env.id` as env_server makes it: `mo:` through MO-Gymnasium,
    `gym:` through gymnasium with its scalar reward as the one objective."""
    kind, _, name = env_id.partition(":")
    if kind == "mo":
        import mo_gymnasium

        return mo_gymnasium.make(name)
    if kind == "gym":
        import gymnasium

        return gymnasium.wrappers.TransformReward(gymnasium.make(name), lambda r: np.array([r]))
    raise SystemExit(f"env.id: expected an MO-Gymnasium (mo:...) or gymnasium (gym:...) task, got {env_id!r}")


def rollout(policy, env_id: str, steps: int) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Observations with the preference appended [T, O], mean actions [T, D], rewards [T, K]."""
    env = make_env(env_id)
    obs, _ = env.reset(seed=1)
    states, means, rewards = [], [], []
    for _ in range(steps):
        x = policy._with_preference(torch.as_tensor(obs, dtype=torch.float32)[None])
        with torch.no_grad():
            mean, _ = policy(x)
        states.append(x[0])
        means.append(mean[0])
        obs, reward, terminated, truncated, _ = env.step(policy.act(obs).numpy())
        rewards.append(reward)
        if terminated or truncated:
            break
    return torch.stack(states), torch.stack(means), np.array(rewards)


def env_of(config: pathlib.Path) -> str:
    """`env.id` of a run's config.toml (the agent writes it first in its [env] table;
    tomllib is 3.11+ and env_server supports 3.10)."""
    found = re.search(r'^\[env\]\s*^id = "([^"]+)"', config.read_text(), re.MULTILINE)
    if not found:
        raise SystemExit(f'{config}: expected an [env] table that starts with id = "..."')
    return found.group(1)


def probe(ckpt: pathlib.Path, preference: dict[str, float] | None, args: argparse.Namespace) -> None:
    state = json.loads((ckpt / "state.json").read_text())
    config, names = state["config"], state["dims"]["reward_names"]
    env_id = env_of(run_dir(ckpt) / "config.toml")
    sources = {o["name"]: o.get("source", "learned") for o in config["objectives"]}
    if any(v != "learned" for v in sources.values()):
        raise SystemExit(f"learner.objectives: expected every source 'learned' (one critic head each), got {sources}")
    policy = load_policy(ckpt, preference)
    critic = Critic(load_file(ckpt / "params.safetensors"), config["network"])
    states, means, rewards = rollout(policy, env_id, args.steps)
    half = max(1, len(states) // 2)
    gamma = config["mpo"]["discount"]
    togo = np.zeros_like(rewards)
    acc = np.zeros(rewards.shape[1])
    for t in range(len(rewards) - 1, -1, -1):
        acc = rewards[t] + gamma * acc
        togo[t] = acc
    x, mean = states[:half], means[:half]
    with torch.no_grad():
        _, std = policy(x)
        samples = mean + std * torch.randn(args.samples, *mean.shape, generator=args.generator)
        q = critic(x, samples)
        q_mean = critic(x, mean[None])[0]
    z = (samples - mean) / std
    z = z - z.mean(0)
    epsilon, eta = grid_point(config, names, preference, state["temperature"])
    label = ",".join(f"{k}={v}" for k, v in (preference or {}).items()) or "fixed ε"
    returns = ", ".join(f"{n} {r:.1f}" for n, r in zip(names, rewards.sum(0)))
    print(f"{label}: return {returns} over {len(rewards)} steps")
    print(
        f"  policy: std median {std.median():.3f} (10%-90% {std.quantile(0.1):.3f}-{std.quantile(0.9):.3f}), "
        f"|mean action| median {mean.abs().median():.3f}"
    )
    for c in range(q.shape[-1]):
        weights = torch.softmax(q[..., c] / eta[c], 0)
        shift = (weights[..., None] * z).sum(0)
        tilt = shift.norm(dim=-1).mean().item()
        spread = (weights[..., None] * (z - shift) ** 2).sum(0)
        print(
            f"  {names[c]}: Q(mu) {q_mean[:, c].mean():9.2f}  G {togo[:half, c].mean():9.2f}  "
            f"sd_M {q[..., c].std(0).mean():7.3f}  eta* {solved_temperature(q[..., c], epsilon[c]):8.3f}  "
            f"eta {eta[c]:8.3f}  tilt {tilt:6.3f}"
        )
        print(
            f"    per action dim: variance asked / sigma^2 {_row(spread.mean(0))}, |mean shift| / sigma {_row(shift.abs().mean(0))}"
        )


def _row(values: torch.Tensor) -> str:
    return "[" + ", ".join(f"{v:.2f}" for v in values.tolist()) + "]"


def grid_point(config: dict, names: list[str], preference: dict[str, float] | None, temperature: list[float]):
    """ε of every objective at this preference and the checkpoint's temperatures there
    (the `[G, K]` table's row; the nearest grid point's for a preference off the grid)."""
    points = grid_points(config, names)
    # As load_policy's features: the middle point by default, else the first one's
    # other values.
    asked = list(points[len(points) // 2] if preference is None else points[0])
    for name, value in (preference or {}).items():
        asked[names.index(name)] = value
    g = min(range(len(points)), key=lambda i: sum(abs(math.log(a / b)) for a, b in zip(points[i], asked)))
    table = np.array(temperature).reshape(len(points), -1)
    # The E-step's ε: rescaled to one sum when the run sets total_epsilon.
    total = (config.get("conditioning") or {}).get("total_epsilon")
    if total is not None:
        asked = [a * total / sum(asked) for a in asked]
    return asked, table[g]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("path", type=pathlib.Path, help="a run directory (its latest checkpoint) or a checkpoint")
    parser.add_argument("--epsilon", action="append", default=[], help="NAME=EPS of a conditioned objective")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--samples", type=int, default=20)
    args = parser.parse_args()
    args.generator = torch.Generator().manual_seed(0)
    ckpt = checkpoint_dir(args.path)
    prefs = [dict([(p.split("=")[0], float(p.split("=")[1]))]) for p in args.epsilon] or [None]
    for preference in prefs:
        probe(ckpt, preference, args)


if __name__ == "__main__":
    main()
