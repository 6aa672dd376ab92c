"""env_server.trained_policy against checkpoints written here the way the agent writes
them (safetensors' numpy API, tensor names and state.json as agent/src/runtime/checkpoint/mod.rs has
them), checked against a numpy transcription of agent/src/core/nets and a hand-derived case.
"""

from __future__ import annotations

import json
import math
import pathlib

import numpy as np
import pytest
import torch
from safetensors.numpy import save_file

from env_server.trained_policy import CategoricalPolicy, GaussianPolicy, flat_obs, load_policy, preference_features


def _network(layers: list[int], tanh_mean: bool = True, min_variance: float = 1e-4) -> dict:
    return {
        "policy_layers": layers,
        "critic_layers": [8, 8],
        "critic_shared_layers": 1,
        "tanh_on_action_mean": tanh_mean,
        "min_variance": min_variance,
        "tanh_on_critic_action": True,
        "architecture": {"kind": "mlp"},
    }


def _params(rng: np.random.Generator, obs_dim: int, layers: list[int], head: int) -> dict[str, np.ndarray]:
    """The policy's VarStore variables, uniform like nn.Linear's init but wider, so the
    activations leave their linear ranges."""
    sizes = [obs_dim, *layers]
    out = {}
    for i, (inputs, outputs) in enumerate(zip(sizes, sizes[1:])):
        out[f"torso.linear_{i}.weight"] = rng.uniform(-1, 1, (outputs, inputs))
        out[f"torso.linear_{i}.bias"] = rng.uniform(-1, 1, outputs)
    out["torso.layer_norm.weight"] = rng.uniform(0.5, 2, layers[0])
    out["torso.layer_norm.bias"] = rng.uniform(-0.5, 0.5, layers[0])
    out["head.weight"] = rng.uniform(-1, 1, (head, layers[-1]))
    out["head.bias"] = rng.uniform(-1, 1, head)
    return {k: v.astype(np.float32) for k, v in out.items()}


def _write(directory: pathlib.Path, params: dict[str, np.ndarray], network: dict, dims: dict) -> pathlib.Path:
    """A run directory with one checkpoint, as the learner saves it."""
    ckpt = directory / "checkpoints" / "step_100"
    ckpt.mkdir(parents=True)
    tensors = {f"policy/policy.{k}": v for k, v in params.items()}
    tensors |= {f"target_policy/policy.{k}": v + 1 for k, v in params.items()}  # must be ignored
    tensors["critic/critic.torso.linear_0.weight"] = np.zeros((8, 3), np.float32)
    tensors["duals/temperature"] = np.ones(2, np.float32)
    save_file(tensors, ckpt / "params.safetensors")
    state = {
        "format_version": 1,
        "step": 100,
        "adam_steps": [100, 100, 100],
        "temperature": [1.0, 1.0],
        "alpha": [1.0, 1.0],
        "config": {"network": network},
        "dims": dims,
    }
    (ckpt / "state.json").write_text(json.dumps(state))
    (directory / "checkpoints" / "latest.json").write_text(json.dumps({"checkpoint": "step_100"}))
    return ckpt


def _layer_norm(h: np.ndarray, p: dict[str, np.ndarray]) -> np.ndarray:
    h = (h - h.mean(-1, keepdims=True)) / np.sqrt(h.var(-1, keepdims=True) + 1e-5)
    return h * p["torso.layer_norm.weight"] + p["torso.layer_norm.bias"]


def _elu(h: np.ndarray) -> np.ndarray:
    return np.where(h > 0, h, np.expm1(h))


def _torso(p: dict[str, np.ndarray], x: np.ndarray, depth: int, carry: int = 0) -> np.ndarray:
    """mlp/mod.rs LayerNormMlp in float64 numpy, carrying the last `carry` input
    columns to every later layer's input and to the output."""
    carried = x[:, x.shape[1] - carry :]
    h = np.tanh(_layer_norm(x @ p["torso.linear_0.weight"].T + p["torso.linear_0.bias"], p))
    for i in range(1, depth):
        h = np.concatenate([h, carried], axis=1)
        h = _elu(h @ p[f"torso.linear_{i}.weight"].T + p[f"torso.linear_{i}.bias"])
    return np.concatenate([h, carried], axis=1)


def test_gaussian_policy_matches_a_numpy_transcription(tmp_path: pathlib.Path) -> None:
    rng = np.random.default_rng(0)
    layers, obs_dim, d = [6, 5, 4], 3, 2
    params = _params(rng, obs_dim, layers, 2 * d)
    dims = {
        "obs_dim": obs_dim,
        "action": {"continuous": {"dim": d}},
        "reward_names": ["task", "action_norm"],
        "obs_leaves": [{"name": "", "dim": obs_dim}],
        "action_bounds": {"low": [-2.0, None], "high": [2.0, None]},  # serde_json's infinity
    }
    _write(tmp_path, params, _network(layers), dims)
    policy = load_policy(tmp_path)  # the run directory: its latest checkpoint
    assert isinstance(policy, GaussianPolicy)

    obs = rng.normal(0, 3, (7, obs_dim)).astype(np.float32)
    out = _torso(params, obs.astype(np.float64), len(layers)) @ params["head.weight"].T + params["head.bias"]
    mean = np.tanh(out[:, :d])
    std = np.log1p(np.exp(out[:, d:])) + math.sqrt(1e-4)
    got_mean, got_std = policy(torch.as_tensor(obs))
    np.testing.assert_allclose(got_mean.detach().numpy(), mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(got_std.detach().numpy(), std, rtol=1e-5, atol=1e-6)
    # The env action: dimension 0 scaled onto [-2, 2], the unbounded one clipped to [-1, 1].
    expected = np.clip(mean, -1, 1) * [2.0, 1.0]
    np.testing.assert_allclose(policy.act(obs).numpy(), expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(policy.act(obs[0]).numpy(), expected[0], rtol=1e-5, atol=1e-6)
    torch.manual_seed(0)
    sampled = policy.act(obs, deterministic=False).numpy()
    assert sampled.shape == (7, d) and not np.allclose(sampled, expected)
    assert np.all(np.abs(sampled) <= [2.0, 1.0])


def test_gaussian_mean_without_tanh_and_bounds_from_before_they_were_stored(tmp_path: pathlib.Path) -> None:
    rng = np.random.default_rng(1)
    params = _params(rng, 4, [5], 2)
    dims = {"obs_dim": 4, "action": {"continuous": {"dim": 1}}, "reward_names": ["r"]}
    policy = load_policy(_write(tmp_path, params, _network([5], tanh_mean=False), dims))
    obs = rng.normal(0, 1, (9, 4)).astype(np.float32)
    raw = _torso(params, obs.astype(np.float64), 1) @ params["head.weight"].T + params["head.bias"]
    np.testing.assert_allclose(policy(torch.as_tensor(obs))[0].detach().numpy(), raw[:, :1], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(policy.act(obs).numpy(), np.clip(raw[:, :1], -1, 1), rtol=1e-5, atol=1e-6)


def test_a_state_independent_std_is_the_std_raw_parameter(tmp_path: pathlib.Path) -> None:
    """network.policy_std = "state_independent": the head gives the mean only and the
    std is softplus(std_raw) + sqrt(min_variance) at every state."""
    rng = np.random.default_rng(2)
    layers, obs_dim, d = [5, 4], 3, 2
    params = _params(rng, obs_dim, layers, d)
    params["std_raw"] = np.array([-1.0, 0.5], np.float32)
    network = _network(layers) | {"policy_std": "state_independent"}
    dims = {"obs_dim": obs_dim, "action": {"continuous": {"dim": d}}, "reward_names": ["r"]}
    policy = load_policy(_write(tmp_path, params, network, dims))
    obs = rng.normal(0, 3, (6, obs_dim)).astype(np.float32)
    out = _torso(params, obs.astype(np.float64), len(layers)) @ params["head.weight"].T + params["head.bias"]
    got_mean, got_std = policy(torch.as_tensor(obs))
    np.testing.assert_allclose(got_mean.detach().numpy(), np.tanh(out), rtol=1e-5, atol=1e-6)
    std = np.log1p(np.exp(params["std_raw"].astype(np.float64))) + math.sqrt(1e-4)
    np.testing.assert_allclose(got_std.detach().numpy(), np.broadcast_to(std, (6, d)), rtol=1e-5, atol=1e-6)
    # The state-dependent layout's head (2 D outputs) does not fit this config.
    params["head.weight"] = rng.uniform(-1, 1, (2 * d, layers[-1])).astype(np.float32)
    with pytest.raises(ValueError, match=r"head.weight: expected shape \[2, 4\], got \[4, 4\]"):
        load_policy(_write(tmp_path / "other", params, network, dims))


def test_every_layer_preference_features_enter_each_later_layer_and_the_head() -> None:
    """network.policy_preference = "every_layer": the observation's `preference` leaf
    (its last columns) is appended again to linear_1's input and to the head's."""
    rng = np.random.default_rng(3)
    layers, env_dim, f, d = [5, 4], 3, 2, 2
    obs_dim = env_dim + f
    params = _params(rng, obs_dim, layers, 2 * d)
    params["torso.linear_1.weight"] = rng.uniform(-1, 1, (4, 5 + f)).astype(np.float32)
    params["head.weight"] = rng.uniform(-1, 1, (2 * d, 4 + f)).astype(np.float32)
    leaves = [{"name": "", "dim": env_dim}, {"name": "preference", "dim": f}]
    dims = {"obs_dim": obs_dim, "action": {"continuous": {"dim": d}}, "reward_names": ["a", "b"], "obs_leaves": leaves}
    policy = GaussianPolicy(_network(layers) | {"policy_preference": "every_layer"}, dims)
    policy.load_state_dict({k: torch.as_tensor(v) for k, v in params.items()})
    obs = rng.normal(0, 3, (6, obs_dim))
    out = _torso(params, obs, len(layers), carry=f) @ params["head.weight"].T + params["head.bias"]
    got_mean, got_std = policy(torch.as_tensor(obs, dtype=torch.float32))
    np.testing.assert_allclose(got_mean.detach().numpy(), np.tanh(out[:, :d]), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(got_std.detach().numpy(), np.log1p(np.exp(out[:, d:])) + 1e-2, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"policy_preference: expected 'input' or 'every_layer', got 'everywhere'"):
        GaussianPolicy(_network(layers) | {"policy_preference": "everywhere"}, dims)


def test_categorical_policy_hand_derived(tmp_path: pathlib.Path) -> None:
    """LayerNorm scale 0 makes the torso output tanh(LayerNorm bias) for every input:
    tanh([0, 0.5]) = [0, 0.4621]; head rows [1, 0], [0, 1], [0, -1] with bias [0, 0, 0.3]
    give the logits [0, 0.4621, -0.1621], so action 1, whatever the observation."""
    params = {
        "torso.linear_0.weight": np.ones((2, 3), np.float32),
        "torso.linear_0.bias": np.zeros(2, np.float32),
        "torso.layer_norm.weight": np.zeros(2, np.float32),
        "torso.layer_norm.bias": np.array([0.0, 0.5], np.float32),
        "head.weight": np.array([[1, 0], [0, 1], [0, -1]], np.float32),
        "head.bias": np.array([0, 0, 0.3], np.float32),
    }
    dims = {"obs_dim": 3, "action": {"discrete": {"n": 3}}, "reward_names": ["time", "treasure"]}
    policy = load_policy(_write(tmp_path, params, _network([2]), dims))
    assert isinstance(policy, CategoricalPolicy)
    obs = np.array([[0, 0, 0], [5, -3, 1]], np.float32)
    np.testing.assert_allclose(policy(torch.as_tensor(obs)).detach().numpy(), [[0, 0.462117, -0.162117]] * 2, atol=1e-6)
    assert policy.act(obs).tolist() == [1, 1] and policy.act(obs[0]).item() == 1
    torch.manual_seed(0)
    assert set(policy.act(np.zeros((200, 3)), deterministic=False).tolist()) == {0, 1, 2}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda p, n, s: p.pop("head.bias"), "missing ['head.bias'], unexpected []"),
        (lambda p, n, s: p.update({"torso.linear_1.weight": p["head.weight"]}), "unexpected ['torso.linear_1.weight']"),
        (
            lambda p, n, s: p.update({"head.weight": p["head.weight"][:1]}),
            "policy/policy.head.weight: expected shape [2, 5], got [1, 5]",
        ),
        (
            lambda p, n, s: n.update({"architecture": {"kind": "transformer"}}),
            "config.network.architecture.kind: expected 'mlp' or 'mocap', got 'transformer'",
        ),
        (
            lambda p, n, s: s.update({"action": {"multi": {}}}),
            "dims.action: expected continuous or discrete, got {'multi': {}}",
        ),
    ],
)
def test_a_checkpoint_that_does_not_fit_is_refused_by_name(tmp_path: pathlib.Path, change, message: str) -> None:
    params = _params(np.random.default_rng(2), 4, [5], 2)
    network = _network([5])
    dims = {"obs_dim": 4, "action": {"continuous": {"dim": 1}}, "reward_names": ["r"]}
    change(params, network, dims)
    ckpt = _write(tmp_path, params, network, dims)
    with pytest.raises(ValueError) as info:
        load_policy(ckpt)
    assert message in str(info.value)


def test_a_checkpoint_of_another_format_is_refused(tmp_path: pathlib.Path) -> None:
    dims = {"obs_dim": 4, "action": {"continuous": {"dim": 1}}, "reward_names": ["r"]}
    ckpt = _write(tmp_path, _params(np.random.default_rng(3), 4, [5], 2), _network([5]), dims)
    state = json.loads((ckpt / "state.json").read_text())
    (ckpt / "state.json").write_text(json.dumps({**state, "format_version": 2}))
    with pytest.raises(ValueError) as info:
        load_policy(ckpt)
    assert str(info.value) == f"{ckpt / 'state.json'}: format_version: expected 1, got 2"


def test_flat_obs_keeps_the_order_the_server_sent_the_leaves_in() -> None:
    """The agent concatenates leaves in message order (agent/src/env/mod.rs to_flat_f32);
    remote.tree rebuilds a Dict observation in that order, not sorted by key."""
    obs = {"z": np.array([1.0, 2.0]), "a": {"y": np.array([[3.0], [4.0]]), "b": np.float64(5.0)}}
    flat = flat_obs(obs)
    assert flat.dtype == np.float32
    assert flat.tolist() == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert flat_obs(np.arange(6).reshape(2, 3)).tolist() == [0, 1, 2, 3, 4, 5]


def test_mocap_policy_matches_a_numpy_transcription(tmp_path: pathlib.Path) -> None:
    """agent/src/core/nets/torso.rs MocapTorso: encoder MLP on the whole observation, latent
    Linear to [mean, log std], the policy MLP on [z, proprioception], where the
    proprioception is every leaf whose name lacks "reference" (here indices 0, 1, 5)."""
    rng = np.random.default_rng(4)
    leaves = [("walker/joints", 2), ("walker/reference_rel", 3), ("walker/velocity", 1)]
    obs_dim, latent, encoder_layers, layers, d = 6, 3, [5, 4], [7], 2
    encoder = _params(rng, obs_dim, encoder_layers, 1)
    torso = _params(rng, latent + 3, layers, 2 * d)
    params = {k.replace("torso.", "encoder."): v for k, v in encoder.items() if k.startswith("torso.")}
    params |= {k: v for k, v in torso.items()}
    params["latent.weight"] = rng.uniform(-1, 1, (2 * latent, encoder_layers[-1])).astype(np.float32)
    params["latent.bias"] = rng.uniform(-1, 1, 2 * latent).astype(np.float32)
    network = _network(layers)
    network["architecture"] = {
        "kind": "mocap",
        "encoder_layers": encoder_layers,
        "latent_dim": latent,
        "reference_match": "reference",
    }
    dims = {
        "obs_dim": obs_dim,
        "action": {"continuous": {"dim": d}},
        "reward_names": ["task"],
        "obs_leaves": [{"name": n, "dim": k} for n, k in leaves],
        "action_bounds": {"low": [-1.0, -1.0], "high": [1.0, 1.0]},
    }
    policy = load_policy(_write(tmp_path, params, network, dims))

    obs = rng.normal(0, 2, (5, obs_dim)).astype(np.float32)
    enc = {k.replace("encoder.", "torso."): v for k, v in params.items() if k.startswith("encoder.")}
    h = _torso(enc, obs.astype(np.float64), len(encoder_layers))
    stats = h @ params["latent.weight"].T + params["latent.bias"]
    xi = rng.normal(0, 1, (5, latent)).astype(np.float32)
    for noise in (None, xi):
        z = stats[:, :latent] + (0 if noise is None else np.exp(np.clip(stats[:, latent:], -5, 2)) * noise)
        x = np.concatenate([z, obs[:, [0, 1, 5]]], axis=1)
        out = _torso(params, x, len(layers)) @ params["head.weight"].T + params["head.bias"]
        got, _ = policy(torch.as_tensor(obs), None if noise is None else torch.as_tensor(noise))
        np.testing.assert_allclose(got.detach().numpy(), np.tanh(out[:, :d]), rtol=1e-5, atol=1e-6)
    # Deterministic: the latent's mean.
    z = stats[:, :latent]
    out = _torso(params, np.concatenate([z, obs[:, [0, 1, 5]]], axis=1), len(layers))
    mean = np.tanh((out @ params["head.weight"].T + params["head.bias"])[:, :d])
    np.testing.assert_allclose(policy.act(obs).numpy(), mean, rtol=1e-5, atol=1e-6)


def test_preference_features_follow_the_agents_grid() -> None:
    """Hand-derived: a conditioned objective's log ε spans [-1, 1] over its list; the
    default is the grid's middle point, with earlier objectives (env order) varying
    slowest, as agent/src/core/algo/preferences/mod.rs builds it."""
    dims = {"reward_names": ["time", "treasure"]}
    objectives = [{"name": "time", "epsilon": 0.02}, {"name": "treasure", "epsilon": 0.1}]
    one = {"objectives": objectives, "conditioning": {"epsilon": {"treasure": [0.005, 0.05, 0.5]}}}
    assert preference_features(one, dims, None) == pytest.approx([0.0])  # 0.05, the middle
    assert preference_features(one, dims, {"treasure": 0.5}) == pytest.approx([1.0])
    # Off the grid: log(0.2 / 0.05) / log(10).
    assert preference_features(one, dims, {"treasure": 0.2}) == pytest.approx([math.log(4) / math.log(10)])
    # Points (time, treasure): (0.01, 0.005), (0.01, 0.5), (0.1, 0.005), (0.1, 0.5); the middle is the third.
    two = {"objectives": objectives, "conditioning": {"epsilon": {"treasure": [0.005, 0.5], "time": [0.01, 0.1]}}}
    assert preference_features(two, dims, None) == pytest.approx([1.0, -1.0])
    # A partial preference keeps the first point's other values.
    assert preference_features(two, dims, {"treasure": 0.5}) == pytest.approx([-1.0, 1.0])


@pytest.mark.parametrize(
    ("conditioning", "epsilon", "message"),
    [
        ({"epsilon": {"treasure": [0.05, 0.5]}}, {"time": 0.1}, "epsilon: 'time' is not a conditioned objective"),
        ({"epsilon": {"treasure": [0.05, 0.5]}}, {"treasure": 0.0}, "epsilon: ε of treasure must be > 0, got 0.0"),
        (None, {"treasure": 0.5}, "epsilon: given only for an ε-conditioned policy"),
    ],
)
def test_a_preference_that_does_not_fit_is_refused_by_name(conditioning, epsilon, message: str) -> None:
    config = {"objectives": [{"name": "time", "epsilon": 0.02}, {"name": "treasure", "epsilon": 0.1}]}
    if conditioning is not None:
        config["conditioning"] = conditioning
    with pytest.raises(ValueError, match=message):
        preference_features(config, {"reward_names": ["time", "treasure"]}, epsilon)
