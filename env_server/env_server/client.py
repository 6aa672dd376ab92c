"""A thin Python client for mo_env.v1.

    with RemoteVectorEnv("127.0.0.1:50051", "dst", num_envs=8, seed=0) as env:
        obs = env.reset()
        obs, reward, terminated, truncated, infos = env.step(actions)   # reward [B, K]

`RemoteEnv` is a single-instance `gymnasium.Env` whose reward is a float32 vector of K
entries, like MO-Gymnasium (with a `reward_space` attribute); with
`render_mode="rgb_array"` its `render()` returns the current frame, so gymnasium's
`RecordVideo` records it. Failed calls raise
`RemoteError` (or a subclass) carrying the gRPC code and message; only UNAVAILABLE
is retried, with exponential backoff.

A server on another host (started with --tls-cert and --auth-token-file) is reached
with an `https://host:port` address (or `tls_ca=`, which implies TLS), `tls_ca=` the CA
file that signed its certificate (default: the system's roots), `token=` or
`token_file=` the bearer token, and for mutual TLS `tls_client_cert=` /
`tls_client_key=`. Every function and class here takes these keywords.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import grpc
import gymnasium
import numpy as np

from env_server import spaces
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
from env_server.session import Autoreset, SessionSpec
from env_server.task import Objective

_PB_TO_DTYPE = {
    pb.DTYPE_FLOAT32: np.dtype(np.float32),
    pb.DTYPE_FLOAT64: np.dtype(np.float64),
    pb.DTYPE_INT32: np.dtype(np.int32),
    pb.DTYPE_INT64: np.dtype(np.int64),
    pb.DTYPE_UINT8: np.dtype(np.uint8),
    pb.DTYPE_BOOL: np.dtype(np.bool_),
}
_DTYPE_TO_PB = {dtype.name: code for code, dtype in _PB_TO_DTYPE.items()}
__all__ = [  # the errors and token reader live in connection.py; users import them from here
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


def to_tensor(arr: np.ndarray) -> pb.Tensor:
    """A numpy array as a wire Tensor (little-endian, row-major)."""
    arr = np.ascontiguousarray(arr)
    return pb.Tensor(dtype=_DTYPE_TO_PB[arr.dtype.name], shape=arr.shape, data=arr.tobytes())


def from_tensor(tensor: pb.Tensor) -> np.ndarray:
    """A wire Tensor as a numpy array (a read-only view of the message bytes)."""
    return np.frombuffer(tensor.data, dtype=_PB_TO_DTYPE[tensor.dtype]).reshape(tuple(tensor.shape))


def _space_spec(space: pb.Space) -> dict[str, Any]:
    kind = space.WhichOneof("kind")
    if kind == "dict":
        return {"dict": [(e.name, _space_spec(e.space)) for e in space.dict.entries]}
    if kind == "discrete":
        return {"discrete": {"n": space.discrete.n, "start": space.discrete.start}}
    box = space.box
    return {
        "box": {
            "dtype": _PB_TO_DTYPE[box.dtype].name,
            "shape": list(box.shape),
            "low": list(box.low),
            "high": list(box.high),
        }
    }


def _objectives(specs: Sequence[pb.ObjectiveSpec]) -> tuple[Objective, ...]:
    # A scale of 0 comes from servers older than the field: nothing was scaled.
    return tuple(Objective(o.name, o.description, o.min, o.max, o.scale or 1.0) for o in specs)


def _tree(named: Sequence[pb.NamedTensor]) -> Any:
    """Leaves back into the observation: one unnamed leaf is the array itself."""
    if len(named) == 1 and not named[0].name:
        return from_tensor(named[0].tensor)
    out: dict[str, Any] = {}
    for leaf in named:
        *parents, last = leaf.name.split(".")
        node = out
        for key in parents:
            node = node.setdefault(key, {})
        node[last] = from_tensor(leaf.tensor)
    return out


def list_envs(address: str, **connection: Any) -> list[tuple[str, str, tuple[Objective, ...]]]:
    """(env_id, description, objectives) for every env the server lists; `connection`
    takes the TLS and token keywords of the module doc."""
    channel = Channel(address, **connection)
    try:
        response = channel.call(channel.stub.ListEnvs, pb.ListEnvsRequest())
    finally:
        channel.close()
    return [(e.env_id, e.description, _objectives(e.objectives)) for e in response.envs]


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
        self._channel = Channel(
            address,
            max_message_mb,
            tls_ca=tls_ca,
            tls_client_cert=tls_client_cert,
            tls_client_key=tls_client_key,
            token=token,
            token_file=token_file,
        )
        if isinstance(autoreset, str):
            autoreset = Autoreset[autoreset.upper()]
        request = pb.MakeRequest(
            env_id=env_id,
            num_envs=num_envs,
            kwargs_json=json.dumps(kwargs) if kwargs else "",
            autoreset_mode=int(autoreset),
            info_keys=list(info_keys),
            num_workers=num_workers,
        )
        if seed is not None:
            request.seed = seed
        if discount is not None:
            request.discount = discount
        response = self._channel.call(self._channel.stub.Make, request)
        self.session_id: str = response.session_id
        self.lease_seconds: float = response.lease_seconds
        s = response.spec
        self.spec = SessionSpec(
            env_id=s.env_id,
            num_envs=s.num_envs,
            observation_space=spaces.spec_to_space(_space_spec(s.observation_space)),
            action_space=spaces.spec_to_space(_space_spec(s.action_space)),
            objectives=_objectives(s.objectives),
            max_episode_steps=s.max_episode_steps,
            autoreset=Autoreset(s.autoreset_mode),
            discount=s.discount,
            info_keys=tuple(s.info_keys),
        )
        self.num_envs = s.num_envs
        self._action_dtype = spaces.leaf_dtype(self.spec.action_space)
        self.cameras: tuple[str, ...] = ()  # the env's named cameras, known after a render()
        self.render_fps = 0.0  # real-time frames per second (0 = unknown), known after a render()
        self.closed = False

    def reset(self, seed: int | Sequence[int] | None = None, env_indices: Sequence[int] = ()) -> Any:
        """Reset instances (all by default); an int seed gives instance i the seed + i."""
        seeds = [] if seed is None else [seed] if isinstance(seed, (int, np.integer)) else list(seed)
        request = pb.ResetRequest(session_id=self.session_id, env_indices=list(env_indices), seeds=seeds)
        return _tree(self._channel.call(self._channel.stub.Reset, request).observation)

    def step(self, actions: Any) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every instance; infos holds "episodes", maybe "final_observation", and info keys."""
        action = to_tensor(np.asarray(actions, dtype=self._action_dtype))
        response = self._channel.call(
            self._channel.stub.Step, pb.StepRequest(session_id=self.session_id, action=action)
        )
        return self.decode_step(response)

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
            infos["final_observation"] = _tree(response.final_observation)
        for leaf in response.info:
            infos[leaf.name] = from_tensor(leaf.tensor)
        return (
            _tree(response.observation),
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
        request = pb.RenderRequest(
            session_id=self.session_id, env_indices=list(env_indices), width=width, height=height, camera=camera
        )
        response = self._channel.call(self._channel.stub.Render, request)
        self.cameras = tuple(response.cameras)
        self.render_fps = response.fps
        return from_tensor(response.frames)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        request = pb.CloseRequest(session_id=self.session_id)
        try:
            try:
                self._channel.call(self._channel.stub.CloseSession, request)
            except RemoteError as exc:
                if exc.code != grpc.StatusCode.UNIMPLEMENTED:
                    raise
                self._channel.call(self._channel.stub.Close, request)  # a server from before CloseSession
        except NotFoundError:
            pass  # already expired on the server
        finally:
            self._channel.close()

    def __enter__(self) -> RemoteVectorEnv:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _first(tree: Any) -> Any:
    return {k: _first(v) for k, v in tree.items()} if isinstance(tree, dict) else tree[0]


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
        spec = self._vec.spec
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
        return _first(self._vec.reset(seed=seed)), {}

    def step(self, action: Any) -> tuple[Any, np.ndarray, bool, bool, dict[str, Any]]:
        batch = np.asarray(action)[None]
        obs, reward, terminated, truncated, infos = self._vec.step(batch)
        info: dict[str, Any] = {k: _first(v) for k, v in infos.items() if k not in ("episodes", "final_observation")}
        if infos["episodes"]:
            info["server_episode"] = infos["episodes"][0]
        return _first(obs), reward[0].copy(), bool(terminated[0]), bool(truncated[0]), info

    def render(self) -> np.ndarray | None:
        """The current frame (render_mode "rgb_array"), else None as gymnasium's envs do."""
        if self.render_mode is None:
            return None
        width, height, camera = self._render_args
        return self._vec.render((0,), width, height, camera)[0]

    def close(self) -> None:
        self._vec.close()
        super().close()
