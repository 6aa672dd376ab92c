"""A thin Python client for mo_env.v1.

    with RemoteVectorEnv("127.0.0.1:50051", "dst", num_envs=8, seed=0) as env:
        obs = env.reset()
        obs, reward, terminated, truncated, infos = env.step(actions)   # reward [B, K]

`RemoteEnv` is a single-instance `gymnasium.Env` whose reward is a float32 vector of K
entries, like MO-Gymnasium (with a `reward_space` attribute); with
`render_mode="rgb_array"` its `render()` returns the current frame, so gymnasium's
`RecordVideo` records it. Failed calls raise
`RemoteError` (or a subclass) carrying the gRPC code and message; only UNAVAILABLE
is retried, with exponential backoff, and never a Step (one sent may have been applied).

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

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.connection import (
    Channel,
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
from env_server.session import Autoreset
from env_server.task import Objective

__all__ = [  # the errors and token reader live in connection.py, the tensors in remote.py
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
    "to_tensor",
]


def list_envs(address: str, **connection: Any) -> list[tuple[str, str, tuple[Objective, ...]]]:
    """(env_id, description, objectives) for every env the server lists; `connection`
    takes the TLS and token keywords of the module doc."""
    channel = Channel(address, **connection)
    try:
        response = channel.call(channel.stub.ListEnvs, pb.ListEnvsRequest())
    finally:
        channel.close()
    return [(e.env_id, e.description, objectives(e.objectives)) for e in response.envs]


class RemoteVectorEnv:
    """A remote session of num_envs instances, stepped as one batch."""

    def __init__(
        self,
        address: str,
        env_id: str,
        num_envs: int,
        seed: int | None = None,
        *,
        autoreset: Autoreset | str = Autoreset.SAME_STEP,
        discount: float | None = None,
        info_keys: Sequence[str] = (),
        num_workers: int = 0,
        max_message_mb: float = 64,
        tls_ca: PathLike | None = None,
        tls_client_cert: PathLike | None = None,
        tls_client_key: PathLike | None = None,
        token: str | None = None,
        token_file: PathLike | None = None,
        **kwargs: Any,
    ) -> None:
        """num_workers >= 1 asks the server to step the instances in that many processes.
        The tls_* and token keywords are the module doc's; other kwargs go to the env."""
        self._session = RemoteSession(
            address,
            env_id,
            num_envs,
            seed,
            autoreset=autoreset_mode(autoreset),
            discount=discount,
            info_keys=info_keys,
            num_workers=num_workers,
            max_message_mb=max_message_mb,
            tls_ca=tls_ca,
            tls_client_cert=tls_client_cert,
            tls_client_key=tls_client_key,
            token=token,
            token_file=token_file,
            kwargs=kwargs,
        )
        self.session_id = self._session.session_id
        self.lease_seconds = self._session.lease_seconds
        self.spec = self._session.spec
        self.num_envs = self.spec.num_envs
        self.cameras: tuple[str, ...] = ()  # the env's named cameras, known after a render()
        self.render_fps = 0.0  # real-time frames per second (0 = unknown), known after a render()

    def reset(self, seed: int | Sequence[int] | None = None, env_indices: Sequence[int] = ()) -> Any:
        """Reset instances (all by default); an int seed gives instance i the seed + i."""
        seeds = [] if seed is None else [seed] if isinstance(seed, (int, np.integer)) else list(seed)
        return tree(self._session.reset(env_indices, seeds).observation)

    def step(self, actions: Any) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every instance; infos holds "episodes", maybe "final_observation", and info keys."""
        return self.decode_step(self._session.step(actions))

    @staticmethod
    def decode_step(response: pb.StepResponse) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        infos: dict[str, Any] = {
            "episodes": [
                {
                    "env_index": e.env_index,
                    "episode_return": np.array(e.episode_return),
                    "discounted_return": np.array(e.discounted_return),
                    "length": e.length,
                    "terminated": e.terminated,
                    "truncated": e.truncated,
                }
                for e in response.episodes
            ]
        }
        if response.final_observation:
            infos["final_observation"] = tree(response.final_observation)
        for leaf in response.info:
            infos[leaf.name] = from_tensor(leaf.tensor)
        return (
            tree(response.observation),
            from_tensor(response.reward),
            np.array(response.terminated, np.bool_),
            np.array(response.truncated, np.bool_),
            infos,
        )

    def render(self, env_indices: Sequence[int] = (), width: int = 0, height: int = 0, camera: str = "") -> np.ndarray:
        """uint8 [len(env_indices) or B, height, width, 3]: the instances' current RGB frames.

        0 = the server's default size (320 x 240); camera "" = the task's default view
        (`cameras` lists the others once a frame was rendered).
        """
        response = self._session.render(env_indices, width, height, camera)
        self.cameras = tuple(response.cameras)
        self.render_fps = response.fps
        return from_tensor(response.frames)

    @property
    def closed(self) -> bool:
        return self._session.closed

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> RemoteVectorEnv:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


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
        self._session = self._vec._session  # the hot path skips the vector env's decoding
        spec = self._session.spec
        self.observation_space = spec.observation_space
        self.action_space = spec.action_space
        self.objectives = spec.objectives
        self.objective_names = tuple(o.name for o in spec.objectives)
        self.reward_space = gymnasium.spaces.Box(
            np.array([o.min for o in spec.objectives], np.float32),
            np.array([o.max for o in spec.objectives], np.float32),
            (len(spec.objectives),),
            np.float32,
        )
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
