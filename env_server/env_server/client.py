"""A thin Python client for mo_env.v1: gymnasium envs whose reward is a vector.

    with RemoteVectorEnv("127.0.0.1:50051", "dst", num_envs=8, seed=0) as envs:
        obs, infos = envs.reset()
        obs, reward, terminated, truncated, infos = envs.step(actions)   # reward [B, K]

`RemoteVectorEnv` is one server session of num_envs instances as a
`gymnasium.vector.VectorEnv`, and `RemoteEnv` one instance as a `gymnasium.Env`. Both
return the reward as a float32 vector of K entries, one per objective, and carry a
`reward_space` of shape (K,), as MO-Gymnasium's envs and vector envs do.

Importing this module registers every shipped env id with gymnasium as
"env_server/<id>" (gymnasium 1.x has no plug-in discovery, so the import does it, or
gymnasium does it for an id written "env_server.client:env_server/<id>"), and
`gymnasium.make("env_server/dst", address=...)` builds a `RemoteEnv`,
`gymnasium.make_vec("env_server/dst", num_envs=8, address=...)` a `RemoteVectorEnv`;
`register(env_id)` adds any other id the server serves (plug-ins; "gym:...", "mo:..."
and "dmc:..." ids with a `name=`).

With `render_mode="rgb_array"` a `RemoteEnv`'s `render()` returns the current frame, so
gymnasium's `RecordVideo` records it. Failed calls raise `RemoteError` (or a subclass)
carrying the gRPC code and message; only UNAVAILABLE is retried, with exponential
backoff, and never a Step (one sent may have been applied). No call waits forever:
`timeout=` (seconds, default 60; None waits forever) bounds each call's wait for its
answer, a Step's on the stream included, and a call without one in time raises
`DeadlineExceededError` (a `TimeoutError`). A Make, Reset or Render that runs out leaves
the session as the server has it; a Step that runs out ends the step stream, whose
sessions the server closes, so that env must be made again.

A server on another host (started with --tls-cert and --auth-token-file) is reached
with an `https://host:port` address (or `tls_ca=`, which implies TLS), `tls_ca=` the CA
file that signed its certificate (default: the system's roots), `token=` or
`token_file=` the bearer token, and for mutual TLS `tls_client_cert=` /
`tls_client_key=`. Every function and class here takes these keywords.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space, create_empty_array

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.connection import (
    DEFAULT_TIMEOUT_S,
    Channel,
    Credentials,
    DeadlineExceededError,
    FailedPreconditionError,
    InvalidArgumentError,
    NotFoundError,
    PathLike,
    PermissionDeniedError,
    RemoteError,
    ResourceExhaustedError,
    UnauthenticatedError,
    read_token_file,
)
from env_server.remote import RemoteSession, autoreset_mode, from_tensor, objectives, to_tensor, tree
from env_server.shared import SHIPPED_ENV_IDS, Autoreset, Objective

__all__ = [  # the errors and token reader live in connection.py, the tensors in remote.py
    "DeadlineExceededError",
    "FailedPreconditionError",
    "InvalidArgumentError",
    "NotFoundError",
    "PermissionDeniedError",
    "RemoteEnv",
    "RemoteError",
    "RemoteVectorEnv",
    "ResourceExhaustedError",
    "UnauthenticatedError",
    "from_tensor",
    "list_envs",
    "read_token_file",
    "register",
    "to_tensor",
]

NAMESPACE = "env_server"
"""gymnasium ids of remote envs are "env_server/<server env id>"."""

_TO_GYM = {
    Autoreset.SAME_STEP: AutoresetMode.SAME_STEP,
    Autoreset.NEXT_STEP: AutoresetMode.NEXT_STEP,
    Autoreset.DISABLED: AutoresetMode.DISABLED,
}
_FROM_GYM = {mode: autoreset for autoreset, mode in _TO_GYM.items()}


def list_envs(
    address: str, *, timeout: float | None = DEFAULT_TIMEOUT_S, **connection: Any
) -> list[tuple[str, str, tuple[Objective, ...]]]:
    """(env_id, description, objectives) for every env the server lists; `connection`
    takes the TLS and token keywords of the module doc."""
    channel = Channel(address, credentials=Credentials(**connection), timeout=timeout)
    try:
        response = channel.call(channel.stub.ListEnvs, pb.ListEnvsRequest())
    finally:
        channel.close()
    return [(e.env_id, e.description, objectives(e.objectives)) for e in response.envs]


def register(env_id: str, name: str | None = None) -> str:
    """Registers a server env id with gymnasium as "env_server/<name>" (name defaults to the
    env id) and returns that id: `make` builds a RemoteEnv, `make_vec` a RemoteVectorEnv,
    both with `address=` and the keywords of their classes. gymnasium reads "module:" off
    an id, so an env id with a colon ("gym:...", "mo:...", "dmc:...") needs a name."""
    name = env_id if name is None else name
    if ":" in name or "/" in name:
        raise ValueError(
            f"name: expected a gymnasium env name without ':' or '/' (gymnasium reads 'module:' and "
            f"'namespace/' off an id), got {name!r}; pass one, e.g. register({env_id!r}, name=...)"
        )
    gym_id = f"{NAMESPACE}/{name}"
    existing = gymnasium.registry.get(gym_id)
    if existing is None:
        gymnasium.register(
            gym_id,
            entry_point="env_server.client:RemoteEnv",
            vector_entry_point="env_server.client:RemoteVectorEnv",
            # gymnasium's checker warns on every vector reward; MO-Gymnasium's make turns it off too.
            disable_env_checker=True,
            kwargs={"env_id": env_id},
        )
    elif existing.kwargs.get("env_id") != env_id:
        raise ValueError(f"name: {gym_id} is registered for env id {existing.kwargs.get('env_id')!r}, got {env_id!r}")
    return gym_id


def _reward_space(objs: Sequence[Objective]) -> gymnasium.spaces.Box:
    low = np.array([o.min for o in objs], np.float32)
    high = np.array([o.max for o in objs], np.float32)
    return gymnasium.spaces.Box(low, high, (len(objs),), np.float32)


def _episode(e: pb.EpisodeEnd) -> dict[str, Any]:
    """The server's record of an ended episode: vector returns [K], length, how it ended."""
    return {
        "episode_return": np.array(e.episode_return),
        "discounted_return": np.array(e.discounted_return),
        "length": e.length,
        "terminated": e.terminated,
        "truncated": e.truncated,
    }


def _at(obs: Any, i: int) -> Any:
    """Instance i of a batched observation (an array or a dict tree of arrays)."""
    return {k: _at(v, i) for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


def _with_rows(obs: Any, rows: Any, indices: list[int]) -> Any:
    """A copy of a batched observation with `rows` written at `indices`."""
    if isinstance(obs, dict):
        return {k: _with_rows(obs[k], rows[k], indices) for k in obs}
    out = np.array(obs)
    out[indices] = rows
    return out


def _reset_seeds(seed: int | Sequence[int | None] | None, indices: list[int] | None, num_envs: int) -> list[int]:
    """ResetRequest.seeds for gymnasium's `seed`: an int s gives instance i the seed s + i."""
    if seed is None:
        return []
    if isinstance(seed, (int, np.integer)):
        return [int(seed)] if indices is None else [int(seed) + i for i in indices]
    seeds = list(seed)
    if len(seeds) != num_envs:
        raise ValueError(f"seed: expected None, an int or {num_envs} seeds (one per instance), got {len(seeds)}")
    chosen = seeds if indices is None else [seeds[i] for i in indices]
    if all(s is None for s in chosen):
        return []
    if any(s is None for s in chosen):
        raise ValueError(
            f"seed: expected a seed for every instance reset or None for all of them (the server "
            f"seeds a Reset's instances all or none), got {chosen}"
        )
    return [int(s) for s in chosen]


class RemoteVectorEnv(gymnasium.vector.VectorEnv):
    """A remote session of num_envs instances as a gymnasium VectorEnv, stepped as one batch.

    The reward is float32 [B, K] with `reward_space` Box (K,), as MO-Gymnasium's vector envs
    have it; `objectives` and `objective_names` say which objective each column is.
    `metadata["autoreset_mode"]` is the session's `autoreset` (SAME_STEP by default, also
    "next_step" or "disabled", or gymnasium's AutoresetMode). reset(seed=s) gives instance i
    the seed s + i; `options={"reset_mask": mask}` resets only the masked instances.

    Infos are gymnasium vector infos: each requested `info_keys` entry is an array [B, ...]
    with a `_key` mask; an instance whose episode ended has the server's record of it under
    `infos["server_episode"]` (`episode_return` and `discounted_return` [B, K], `length`,
    `terminated`, `truncated`, each masked), and under SAME_STEP its last observation in
    `infos["final_obs"]` and last info in `infos["final_info"]`, as gymnasium's SyncVectorEnv
    puts them. The key "episode" is left to gymnasium's RecordEpisodeStatistics and
    MO-Gymnasium's MORecordEpisodeStatistics, which write it (the latter counts with
    NEXT_STEP autoreset). Observations are read-only views of the received message.

    num_workers >= 1 asks the server to step the instances in that many processes. The
    timeout, tls_* and token keywords are the module doc's; other kwargs go to the env's
    constructor.
    """

    def __init__(
        self,
        address: str,
        env_id: str,
        num_envs: int,
        seed: int | None = None,
        *,
        autoreset: Autoreset | AutoresetMode | str = Autoreset.SAME_STEP,
        discount: float | None = None,
        info_keys: Sequence[str] = (),
        num_workers: int = 0,
        max_message_mb: float = 64,
        timeout: float | None = DEFAULT_TIMEOUT_S,
        tls_ca: PathLike | None = None,
        tls_client_cert: PathLike | None = None,
        tls_client_key: PathLike | None = None,
        token: str | None = None,
        token_file: PathLike | None = None,
        **kwargs: Any,
    ) -> None:
        mode = _FROM_GYM[autoreset] if isinstance(autoreset, AutoresetMode) else autoreset_mode(autoreset)
        self._session = RemoteSession(
            address,
            env_id,
            num_envs,
            seed,
            autoreset=mode,
            discount=discount,
            info_keys=info_keys,
            num_workers=num_workers,
            max_message_mb=max_message_mb,
            credentials=Credentials(tls_ca, tls_client_cert, tls_client_key, token, token_file),
            timeout=timeout,
            kwargs=kwargs,
        )
        spec = self.session_spec = self._session.spec
        self.session_id = self._session.session_id
        self.lease_seconds = self._session.lease_seconds
        self.num_envs = spec.num_envs
        self.single_observation_space = spec.observation_space
        self.single_action_space = spec.action_space
        self.observation_space = batch_space(spec.observation_space, self.num_envs)
        self.action_space = batch_space(spec.action_space, self.num_envs)
        self.objectives = spec.objectives
        self.objective_names = tuple(o.name for o in spec.objectives)
        self.reward_space = _reward_space(spec.objectives)
        self.metadata = {"autoreset_mode": _TO_GYM[spec.autoreset], "render_modes": ["rgb_array"]}
        self.cameras: tuple[str, ...] = ()  # the env's named cameras, known after a render()
        self.render_fps = 0.0  # real-time frames per second (0 = unknown), known after a render()
        # The last observation of every instance: a partial reset returns it for the others.
        self._obs = create_empty_array(self.single_observation_space, self.num_envs, fn=np.zeros)

    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Reset every instance, or those of options["reset_mask"] (bool [B])."""
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"options: expected at most the key 'reset_mask', got also {sorted(options)}")
        indices = None if mask is None else self._masked(mask)
        if isinstance(seed, (int, np.integer)):
            self._np_random, self._np_random_seed = seeding.np_random(int(seed))
        response = self._session.reset(indices or (), _reset_seeds(seed, indices, self.num_envs))
        obs = tree(response.observation)
        self._obs = obs if indices is None else _with_rows(self._obs, obs, indices)
        infos: dict[str, Any] = {}
        rows = range(self.num_envs) if indices is None else indices
        for leaf in response.info:
            value = from_tensor(leaf.tensor)
            for pos, i in enumerate(rows):
                self._add_info(infos, {leaf.name: value[pos]}, i)
        return self._obs, infos

    def _masked(self, mask: Any) -> list[int]:
        arr = np.asarray(mask)
        if arr.dtype != np.bool_ or arr.shape != (self.num_envs,) or not arr.any():
            raise ValueError(
                f"options['reset_mask']: expected bool [{self.num_envs}] (num_envs) with at least one True, "
                f"got {arr.dtype} {list(arr.shape)} {arr.tolist()}"
            )
        return np.flatnonzero(arr).tolist()

    def step(self, actions: Any) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every instance with actions [B, ...]; reward [B, K]."""
        response = self._session.step(actions)
        obs = self._obs = tree(response.observation)
        infos: dict[str, Any] = {}
        for leaf in response.info:
            infos[leaf.name] = from_tensor(leaf.tensor)
            infos[f"_{leaf.name}"] = np.ones(self.num_envs, np.bool_)
        finals = tree(response.final_observation) if response.final_observation else None
        for pos, e in enumerate(response.episodes):
            i = e.env_index
            ended: dict[str, Any] = {"server_episode": _episode(e)}
            if finals is not None:
                ended["final_obs"] = _at(finals, pos)
                ended["final_info"] = {leaf.name: infos[leaf.name][i] for leaf in response.info}
            self._add_info(infos, ended, i)
        terminated = np.array(response.terminated, np.bool_)
        truncated = np.array(response.truncated, np.bool_)
        return obs, from_tensor(response.reward), terminated, truncated, infos

    def render(self, env_indices: Sequence[int] = (), width: int = 0, height: int = 0, camera: str = "") -> np.ndarray:
        """uint8 [len(env_indices) or B, height, width, 3]: the instances' current RGB frames.

        0 = the server's default size (320 x 240); camera "" = the task's default view
        (`cameras` lists the others once a frame was rendered).
        """
        response = self._session.render(env_indices, width, height, camera)
        self.cameras = tuple(response.cameras)
        self.render_fps = response.fps
        return from_tensor(response.frames)

    def close_extras(self, **kwargs: Any) -> None:
        self._session.close()

    def __enter__(self) -> RemoteVectorEnv:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class RemoteEnv(gymnasium.Env):
    """One remote instance as a gymnasium.Env with a vector reward (like MO-Gymnasium).

    Autoreset is DISABLED, so this behaves like a plain gymnasium env: call reset()
    after an episode ends. The step that ends an episode puts the server's record of it
    in `info["server_episode"]` (vector `episode_return` and `discounted_return`,
    `length`, ...). Not `info["episode"]`: gymnasium's RecordEpisodeStatistics and
    MO-Gymnasium's MORecordEpisodeStatistics write that key and assert it is free.

    `render_mode="rgb_array"` (gymnasium's convention) makes `render()` return the current
    frame, uint8 [render_height, render_width, 3] from `render_camera` ("" = the task's
    default view); `render_fps` is what video writers such as `RecordVideo` read from
    `metadata`. The connection keywords (module docstring) go to the connection; other
    keyword arguments go to the env's constructor on the server.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        address: str,
        env_id: str,
        seed: int | None = None,
        *,
        render_mode: str | None = None,
        render_width: int = 0,
        render_height: int = 0,
        render_camera: str = "",
        render_fps: float = 30,
        **kwargs: Any,
    ) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(
                f"render_mode: expected None or one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.render_mode = render_mode
        self._render_args = (render_width, render_height, render_camera)
        self.metadata = {**self.metadata, "render_fps": render_fps}
        self._vec = RemoteVectorEnv(address, env_id, 1, seed, autoreset=Autoreset.DISABLED, **kwargs)
        self._session = self._vec._session  # the hot path skips the vector env's info building
        spec = self._session.spec
        self.observation_space = spec.observation_space
        self.action_space = spec.action_space
        self.objectives = spec.objectives
        self.objective_names = self._vec.objective_names
        self.reward_space = self._vec.reward_space
        self.max_episode_steps = spec.max_episode_steps or None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        response = self._session.reset((), () if seed is None else (seed,))
        info = {leaf.name: from_tensor(leaf.tensor)[0] for leaf in response.info}
        return _at(tree(response.observation), 0), info

    def step(self, action: Any) -> tuple[Any, np.ndarray, bool, bool, dict[str, Any]]:
        response = self._session.step(np.asarray(action)[None])
        info: dict[str, Any] = {leaf.name: from_tensor(leaf.tensor)[0] for leaf in response.info}
        if response.episodes:
            info["server_episode"] = _episode(response.episodes[0])
        reward = from_tensor(response.reward)[0].copy()
        return _at(tree(response.observation), 0), reward, response.terminated[0], response.truncated[0], info

    def render(self) -> np.ndarray | None:
        """The current frame (render_mode "rgb_array"), else None as gymnasium's envs do."""
        if self.render_mode is None:
            return None
        width, height, camera = self._render_args
        return self._vec.render((0,), width, height, camera)[0]

    def close(self) -> None:
        self._vec.close()
        super().close()


for _env_id in SHIPPED_ENV_IDS:
    register(_env_id)
