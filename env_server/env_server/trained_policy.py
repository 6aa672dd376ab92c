"""The agent's trained policies in PyTorch: a checkpoint as a `torch.nn.Module`.

    from env_server.trained_policy import load_policy

    policy = load_policy("runs/pendulum__mompo__0__20261125-091122")  # its latest checkpoint
    action = policy.act(obs)  # the env action, deterministic: the mean / the most likely

A checkpoint is a directory the agent writes (agent/src/runtime/checkpoint/mod.rs): `state.json`
carries the network config and the dimensions the learner was built for, and
`params.safetensors` the online policy's parameters under `policy/<VarStore name>`
(the target networks, critics and duals there are ignored). A run directory means its
latest checkpoint (`checkpoints/latest.json`). Needs torch and safetensors.

The networks are transcribed from agent/src/core/nets (mlp/mod.rs, policy.rs, torso.rs):
- torso: Linear -> LayerNorm (eps 1e-5) -> tanh, then Linear -> ELU per further size of
  `network.policy_layers` (parameters `torso.linear_0`, `torso.layer_norm`,
  `torso.linear_<i>`); with `network.policy_preference = "every_layer"` the
  observation's last columns, its `preference` leaf, are appended again to the input of
  every `torso.linear_<i>` after the first and to the torso's output;
- mocap torso (A.3): `encoder` (such an MLP of `encoder_layers`) on the observation,
  `latent` Linear to the latent's mean and log std, and `torso` on [latent, the
  proprioceptive leaves];
- Gaussian head (continuous actions, D dims): Linear to [mean_raw, std_raw];
  mean = tanh(mean_raw) when `network.tanh_on_action_mean`, std = softplus(std_raw) +
  sqrt(`network.min_variance`); with `network.policy_std = "state_independent"` the
  Linear gives mean_raw only and std_raw is the parameter `std_raw` [D];
- categorical head (A discrete actions): Linear to the logits.

`act` returns what the agent's actor sends the env: a Gaussian action clipped to
[-1, 1] and mapped linearly onto the action space's bounds where both are finite
(`ActionBounds::to_env`), or an action index (add the space's `start` where it is not 0).
Observations are flat float vectors [obs_dim] or [B, obs_dim], leaves in the order of
the checkpoint's `dims.obs_leaves` (`flat_obs` flattens a RemoteEnv's Dict observation
so). A mocap policy acts on its latent's mean when deterministic, on a sampled latent
otherwise.

`evaluate` runs a policy on RemoteEnv instances the way `agent eval` does, so the same
checkpoint gives the returns `agent eval` prints:

    from env_server.trained_policy import evaluate

    episodes = evaluate(policy, "127.0.0.1:50051", "pendulum", episodes=10, seed=1_000_000, num_envs=8)
    [e["episode_return"] for e in episodes]  # the server's vector returns

`agent act --checkpoint RUN --observations OBS.npy --out ACTIONS.npy` writes the agent's
own deterministic actions for given observations, to compare `act` with.

An ε-conditioned policy (one run for a whole front) acts at the preference given to
`load_policy(run, epsilon={"treasure": 0.5})`, or at its grid's middle point.
"""

from __future__ import annotations

import json
import math
import pathlib
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file
from torch import nn

from env_server.client import RemoteEnv

FORMAT_VERSION = 1  # agent/src/runtime/checkpoint/mod.rs FORMAT_VERSION
PREFIX = "policy/policy."  # the checkpoint's "policy/" and the VarStore's root "policy"


class Torso(nn.Module):
    """Linear -> LayerNorm -> tanh, then Linear -> ELU per further hidden size; the last
    `carry` input columns (preference features) appended again to every later layer's
    input and to the output."""

    def __init__(self, obs_dim: int, layers: list[int], carry: int = 0) -> None:
        super().__init__()
        self.carry = carry
        self.output_dim = layers[-1] + carry
        self.linear_0 = nn.Linear(obs_dim, layers[0])
        self.layer_norm = nn.LayerNorm(layers[0], eps=1e-5)
        self.hidden = [f"linear_{i}" for i in range(1, len(layers))]
        for name, (inputs, outputs) in zip(self.hidden, zip(layers, layers[1:])):
            self.add_module(name, nn.Linear(inputs + carry, outputs))

    def _carried(self, h: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return torch.cat([h, obs[..., obs.shape[-1] - self.carry :]], dim=-1) if self.carry else h

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """[B, obs_dim] -> [B, output_dim]."""
        h = torch.tanh(self.layer_norm(self.linear_0(obs)))
        for name in self.hidden:
            h = nn.functional.elu(getattr(self, name)(self._carried(h, obs)))
        return self._carried(h, obs)


class _Policy(nn.Module):
    """The torso every policy shares: `torso` on the observation (mlp), or A.3's mocap
    encoder: `encoder` (an MLP as Torso) on the whole observation, `latent` (Linear) to
    the latent's mean and log std (clamped to [-5, 2]), and `torso` on [z,
    proprioception], the proprioception being the leaves whose name lacks
    `reference_match` (agent/src/core/nets/torso.rs). Parameters sit at the policy's root,
    as in the agent's VarStore."""

    #: An ε-conditioned policy's preference features [F], appended to every observation
    #: `act` is given (empty: not conditioned); set by `load_policy`.
    preference: torch.Tensor

    def _with_preference(self, x: torch.Tensor) -> torch.Tensor:
        if not self.preference.numel():
            return x
        return torch.cat([x, self.preference.expand(x.shape[0], -1)], dim=1)

    def _build_torso(self, network: dict[str, Any], dims: dict[str, Any]) -> None:
        self.register_buffer("preference", torch.zeros(0), persistent=False)
        arch = network.get("architecture", {"kind": "mlp"})
        layers = network["policy_layers"]
        self.latent_dim = 0
        if arch["kind"] == "mlp":
            self.torso = Torso(dims["obs_dim"], layers, _carried_features(network, dims))
            return
        encoder_layers = arch.get("encoder_layers", [1024, 1024])  # the agent's defaults
        self.latent_dim = arch.get("latent_dim", 60)
        pattern = arch.get("reference_match", "reference")
        proprio, start = [], 0
        for leaf in dims.get("obs_leaves", []):
            if pattern not in leaf["name"]:
                proprio.extend(range(start, start + leaf["dim"]))
            start += leaf["dim"]
        self.encoder = Torso(dims["obs_dim"], encoder_layers)
        self.latent = nn.Linear(encoder_layers[-1], 2 * self.latent_dim)
        self.register_buffer("proprio_idx", torch.tensor(proprio, dtype=torch.int64), persistent=False)
        self.torso = Torso(self.latent_dim + len(proprio), layers)

    def features(self, obs: torch.Tensor, latent_noise: torch.Tensor | None = None) -> torch.Tensor:
        """[B, obs_dim] -> [B, policy_layers[-1]]; a mocap torso uses the latent's mean
        unless given the noise xi [B, latent_dim] (z = mean + std * xi)."""
        if not self.latent_dim:
            return self.torso(obs)
        mean, log_std = self.latent(self.encoder(obs)).split(self.latent_dim, dim=-1)
        z = mean if latent_noise is None else mean + log_std.clamp(-5.0, 2.0).exp() * latent_noise
        return self.torso(torch.cat([z, obs.index_select(-1, self.proprio_idx)], dim=-1))

    def _noise(self, x: torch.Tensor) -> torch.Tensor | None:
        """Fresh latent noise for a sampled action (None without a latent)."""
        return torch.randn(x.shape[0], self.latent_dim) if self.latent_dim else None


class GaussianPolicy(_Policy):
    """A diagonal Gaussian over D action dims; `forward` gives its mean and std [B, D]."""

    def __init__(self, network: dict[str, Any], dims: dict[str, Any]) -> None:
        super().__init__()
        self.action_dim = dims["action"]["continuous"]["dim"]
        self._build_torso(network, dims)
        std = network.get("policy_std", "state_dependent")
        if std not in ("state_dependent", "state_independent"):
            raise ValueError(
                f"config.network.policy_std: expected 'state_dependent' or 'state_independent', got {std!r}"
            )
        self.std_raw = nn.Parameter(torch.zeros(self.action_dim)) if std == "state_independent" else None
        self.head = nn.Linear(self.torso.output_dim, self.action_dim * (1 if self.std_raw is not None else 2))
        self.tanh_mean = bool(network["tanh_on_action_mean"])
        self.min_std = math.sqrt(network["min_variance"])
        low, high = _bounds(dims.get("action_bounds"), self.action_dim)
        finite = torch.isfinite(low) & torch.isfinite(high)
        self.register_buffer("action_center", torch.where(finite, (low + high) / 2, 0.0), persistent=False)
        self.register_buffer("action_scale", torch.where(finite, (high - low) / 2, 1.0), persistent=False)

    def forward(self, obs: torch.Tensor, latent_noise: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.head(self.features(obs, latent_noise))
        if self.std_raw is None:
            mean_raw, std_raw = out.split(self.action_dim, dim=-1)
        else:
            mean_raw, std_raw = out, self.std_raw.expand_as(out)
        mean = torch.tanh(mean_raw) if self.tanh_mean else mean_raw
        return mean, nn.functional.softplus(std_raw) + self.min_std

    @torch.no_grad()
    def act(self, obs: Any, deterministic: bool = True) -> torch.Tensor:
        """The env action [D] or [B, D]: the mean (or a sample, with a sampled latent
        for a mocap torso), clipped and scaled."""
        x, batched = _obs(obs)
        x = self._with_preference(x)
        mean, std = self(x) if deterministic else self(x, self._noise(x))
        action = mean if deterministic else mean + std * torch.randn_like(mean)
        env_action = action.clamp(-1.0, 1.0) * self.action_scale + self.action_center
        return env_action if batched else env_action[0]


class CategoricalPolicy(_Policy):
    """A categorical distribution over A actions; `forward` gives its logits [B, A]."""

    def __init__(self, network: dict[str, Any], dims: dict[str, Any]) -> None:
        super().__init__()
        self._build_torso(network, dims)
        self.head = nn.Linear(self.torso.output_dim, dims["action"]["discrete"]["n"])

    def forward(self, obs: torch.Tensor, latent_noise: torch.Tensor | None = None) -> torch.Tensor:
        return self.head(self.features(obs, latent_noise))

    @torch.no_grad()
    def act(self, obs: Any, deterministic: bool = True) -> torch.Tensor:
        """The action index (int64), [] or [B]: the most likely, or a sample (with a
        sampled latent for a mocap torso)."""
        x, batched = _obs(obs)
        x = self._with_preference(x)
        logits = self(x) if deterministic else self(x, self._noise(x))
        if deterministic:
            action = logits.argmax(-1)
        else:
            action = torch.distributions.Categorical(logits=logits).sample()
        return action if batched else action[0]


def _carried_features(network: dict[str, Any], dims: dict[str, Any]) -> int:
    """How many preference features every layer of the torso reads again: the
    observation's `preference` leaf with `network.policy_preference = "every_layer"`."""
    where = network.get("policy_preference", "input")
    if where not in ("input", "every_layer"):
        raise ValueError(f"config.network.policy_preference: expected 'input' or 'every_layer', got {where!r}")
    if where == "input":
        return 0
    return sum(leaf["dim"] for leaf in dims.get("obs_leaves", []) if leaf["name"] == "preference")


def checkpoint_dir(path: str | pathlib.Path) -> pathlib.Path:
    """A checkpoint directory as given, or a run directory's latest checkpoint."""
    path = pathlib.Path(path)
    latest = path / "checkpoints" / "latest.json"
    if latest.exists():
        return path / "checkpoints" / json.loads(latest.read_text())["checkpoint"]
    return path


def load_policy(
    path: str | pathlib.Path, epsilon: dict[str, float] | None = None
) -> GaussianPolicy | CategoricalPolicy:
    """The online policy of a checkpoint directory, or of a run directory's latest one.

    An ε-conditioned policy (`learner.conditioning`) acts at `epsilon` (conditioned
    objective -> ε > 0, on its training grid or not; default: the grid's middle point),
    as `agent act --epsilon` and `agent eval --epsilon` do: `act` takes the env's
    observations and appends the preference features itself."""
    path = checkpoint_dir(path)
    state = json.loads((path / "state.json").read_text())
    if state.get("format_version") != FORMAT_VERSION:
        raise ValueError(
            f"{path / 'state.json'}: format_version: expected {FORMAT_VERSION}, got {state.get('format_version')!r}"
        )
    network, dims = state["config"]["network"], state["dims"]
    kind = network.get("architecture", {"kind": "mlp"})["kind"]
    if kind not in ("mlp", "mocap"):
        raise ValueError(
            f"{path / 'state.json'}: config.network.architecture.kind: expected 'mlp' or 'mocap', got {kind!r}"
        )
    action = dims["action"]
    if "continuous" in action:
        policy: GaussianPolicy | CategoricalPolicy = GaussianPolicy(network, dims)
    elif "discrete" in action:
        policy = CategoricalPolicy(network, dims)
    else:
        raise ValueError(f"{path / 'state.json'}: dims.action: expected continuous or discrete, got {action!r}")
    params = load_file(path / "params.safetensors")
    ours = {name[len(PREFIX) :]: t for name, t in params.items() if name.startswith(PREFIX)}
    expected = policy.state_dict()
    missing = sorted(set(expected) - set(ours))
    unexpected = sorted(set(ours) - set(expected))
    if missing or unexpected:
        raise ValueError(
            f"{path / 'params.safetensors'}: expected the tensors {PREFIX}<name> for {sorted(expected)}, "
            f"missing {missing}, unexpected {unexpected}"
        )
    for name, tensor in ours.items():
        if tensor.shape != expected[name].shape:
            raise ValueError(
                f"{path / 'params.safetensors'}: {PREFIX}{name}: expected shape "
                f"{list(expected[name].shape)}, got {list(tensor.shape)}"
            )
    policy.load_state_dict(ours)
    policy.preference = torch.tensor(preference_features(state["config"], dims, epsilon), dtype=torch.float32)
    return policy.eval()


def grid_points(config: dict[str, Any], names: list[str]) -> list[list[float]]:
    """The ε vectors (in `names` order) of a conditioned learner `config`'s grid, as
    agent/src/core/algo/preferences/mod.rs orders them: the product of the conditioned
    objectives' ε lists in env objective order, earlier objectives varying slowest;
    one point, the fixed ε, when it is not conditioned."""
    fixed = {o["name"]: o["epsilon"] for o in config["objectives"]}
    lists = (config.get("conditioning") or {}).get("epsilon", {})
    points = [[fixed[name] for name in names]]
    for name in [n for n in names if n in lists]:
        k = names.index(name)
        points = [p[:k] + [v] + p[k + 1 :] for p in points for v in lists[name]]
    return points


def preference_features(config: dict[str, Any], dims: dict[str, Any], epsilon: dict[str, float] | None) -> list[float]:
    """The input features of preference `epsilon` for a learner `config` (`[]` when it
    is not conditioned), transcribed from agent/src/core/algo/preferences/mod.rs: the grid is
    the product of the conditioned objectives' ε lists in env objective order (earlier
    objectives vary slowest), and each conditioned objective's feature is log ε scaled
    so that its list spans [-1, 1]. A partial `epsilon` keeps the first grid point's
    other values."""
    conditioning = config.get("conditioning")
    if conditioning is None:
        if epsilon:
            raise ValueError(
                "epsilon: given only for an ε-conditioned policy (learner.conditioning); "
                f"this checkpoint's policy has its ε fixed, got {epsilon}"
            )
        return []
    names = list(dims["reward_names"])
    lists = conditioning["epsilon"]
    axes = [name for name in names if name in lists]
    points = grid_points(config, names)
    if epsilon is None:
        eps = points[len(points) // 2]
    else:
        eps = list(points[0])
        for name, value in epsilon.items():
            if name not in axes:
                raise ValueError(f"epsilon: {name!r} is not a conditioned objective (conditioned: {axes})")
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"epsilon: ε of {name} must be > 0, got {value}")
            eps[names.index(name)] = value
    features = []
    for name in axes:
        logs = [math.log(v) for v in lists[name]]
        lo, hi = min(logs), max(logs)
        half = (hi - lo) / 2 if hi > lo else 1.0
        features.append((math.log(eps[names.index(name)]) - (lo + hi) / 2) / half)
    return features


def _bounds(bounds: dict[str, Any] | None, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    """ActionBounds as tensors; serde_json writes an infinite bound as null. No bounds (a
    checkpoint from before they were stored) means actions are clipped to [-1, 1]."""
    if bounds is None:
        return torch.full((dim,), -1.0), torch.full((dim,), 1.0)

    def side(values: list[float | None], missing: float) -> torch.Tensor:
        return torch.tensor([missing if v is None else v for v in values], dtype=torch.float32)

    return side(bounds["low"], -math.inf), side(bounds["high"], math.inf)


def _obs(obs: Any) -> tuple[torch.Tensor, bool]:
    x = torch.as_tensor(obs, dtype=torch.float32)
    return (x, True) if x.dim() == 2 else (x.unsqueeze(0), False)


def flat_obs(obs: Any) -> np.ndarray:
    """One observation as the agent's flat float32 vector: an array flattened, a Dict
    observation's leaves depth-first in the order the server sent them (the order of
    the checkpoint's `dims.obs_leaves`)."""
    if isinstance(obs, dict):
        return np.concatenate([flat_obs(v) for v in obs.values()])
    return np.asarray(obs, np.float32).reshape(-1)


def evaluate(
    policy: GaussianPolicy | CategoricalPolicy,
    address: str,
    env_id: str,
    episodes: int = 10,
    *,
    seed: int = 0,
    num_envs: int = 1,
    **kwargs: Any,
) -> list[dict[str, Any]]:
    """The server's records of the first `episodes` episodes that end when `policy` acts
    deterministically on `num_envs` RemoteEnv instances stepped together; instance i is
    first reset with the seed `seed + i` and again (unseeded) whenever its episode ends.

    Each record has the vector `episode_return` and `discounted_return`, `length`,
    `terminated`, `truncated`, and `env_index`; episodes ending at the same step come in
    instance order. `agent eval --episodes N` on a run is this with num_envs =
    min(N, the run's env.num_envs), seed = the run's seed + 1000000 and the run's
    env.kwargs (agent/src/runtime/eval.rs). Connection keywords (tls_ca, token, ...) and env
    kwargs go to RemoteEnv.
    """
    envs = [RemoteEnv(address, env_id, seed + i, **kwargs) for i in range(num_envs)]
    try:
        start = getattr(envs[0].action_space, "start", 0)  # a Discrete space's first action
        obs = [flat_obs(env.reset()[0]) for env in envs]
        done: list[dict[str, Any]] = []
        while len(done) < episodes:
            actions = policy.act(np.stack(obs)).numpy()
            for i, env in enumerate(envs):
                action = actions[i] + start if isinstance(policy, CategoricalPolicy) else actions[i]
                ob, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    done.append({**info["server_episode"], "env_index": i})
                    ob, _ = env.reset()
                obs[i] = flat_obs(ob)
        return done[:episodes]
    finally:
        for env in envs:
            env.close()
