"""One session on a mo_env.v1 server, in numpy terms: what `client.RemoteEnv` and
`client.RemoteVectorEnv` share (Make, Reset, Step, Render, Close and the wire's tensors).

Steps go over one StepStream rather than a unary Step per call: a message on an open
stream skips the per-call setup of a unary call, about a quarter of a B = 1 round trip
(scripts/bench_client.py). A bad action's error status leaves the session usable on the
server (docs/env-server.md, "The protocol"), so after a failed step the next one opens a new stream.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import grpc
import numpy as np

from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.connection import Channel, Credentials, NotFoundError, RemoteError, Stream
from env_server.shared import Autoreset, ClosedForm, Objective, SessionSpec, leaf_dtype, spec_to_space

_PB_TO_DTYPE = {
    pb.DTYPE_FLOAT32: np.dtype(np.float32),
    pb.DTYPE_FLOAT64: np.dtype(np.float64),
    pb.DTYPE_INT32: np.dtype(np.int32),
    pb.DTYPE_INT64: np.dtype(np.int64),
    pb.DTYPE_UINT8: np.dtype(np.uint8),
    pb.DTYPE_BOOL: np.dtype(np.bool_),
}
_DTYPE_TO_PB = {dtype.name: code for code, dtype in _PB_TO_DTYPE.items()}


def to_tensor(arr: np.ndarray) -> pb.Tensor:
    """A numpy array as a wire Tensor (little-endian, row-major)."""
    arr = np.ascontiguousarray(arr)
    return pb.Tensor(dtype=_DTYPE_TO_PB[arr.dtype.name], shape=arr.shape, data=arr.tobytes())


def from_tensor(tensor: pb.Tensor) -> np.ndarray:
    """A wire Tensor as a numpy array (a read-only view of the message bytes)."""
    return np.frombuffer(tensor.data, dtype=_PB_TO_DTYPE[tensor.dtype]).reshape(tuple(tensor.shape))


def tree(named: Sequence[pb.NamedTensor]) -> Any:
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


#: ObjectiveSpec.closed_form read back; UNSPECIFIED (servers older than the field) and
#: values this client does not know are UNDECLARED.
_CLOSED_FORM_FROM_PB = {pb.CLOSED_FORM_NONE: ClosedForm.NONE, pb.CLOSED_FORM_ACTION_NORM: ClosedForm.ACTION_NORM}


def objectives(specs: Sequence[pb.ObjectiveSpec]) -> tuple[Objective, ...]:
    # A scale of 0 comes from servers older than the field: nothing was scaled.
    return tuple(
        Objective(
            o.name,
            o.description,
            o.min,
            o.max,
            o.scale or 1.0,
            _CLOSED_FORM_FROM_PB.get(o.closed_form, ClosedForm.UNDECLARED),
        )
        for o in specs
    )


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


def autoreset_mode(value: Autoreset | str) -> Autoreset:
    """An Autoreset, or its name in any case ("same_step", "next_step", "disabled")."""
    if isinstance(value, Autoreset):
        return value
    try:
        return Autoreset[str(value).upper()]
    except KeyError:
        names = [m.name.lower() for m in Autoreset]
        raise ValueError(f"autoreset: expected an Autoreset or one of {names}, got {value!r}") from None


class RemoteSession:
    """A session of num_envs instances on a server; see client.RemoteVectorEnv for the arguments."""

    def __init__(
        self,
        address: str,
        env_id: str,
        num_envs: int,
        seed: int | None,
        *,
        autoreset: Autoreset,
        discount: float | None,
        info_keys: Sequence[str],
        num_workers: int,
        max_message_mb: float,
        credentials: Credentials,
        timeout: float | None,
        kwargs: dict[str, Any],
    ) -> None:
        self._channel = Channel(address, max_message_mb, credentials=credentials, timeout=timeout)
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
        try:
            response = self._channel.call(self._channel.stub.Make, request)
        except BaseException:
            self._channel.close()
            raise
        self.session_id: str = response.session_id
        self.lease_seconds: float = response.lease_seconds
        s = response.spec
        self.spec = SessionSpec(
            env_id=s.env_id,
            num_envs=s.num_envs,
            observation_space=spec_to_space(_space_spec(s.observation_space)),
            action_space=spec_to_space(_space_spec(s.action_space)),
            objectives=objectives(s.objectives),
            max_episode_steps=s.max_episode_steps,
            autoreset=Autoreset(s.autoreset_mode),
            discount=s.discount,
            info_keys=tuple(s.info_keys),
        )
        action_dtype = leaf_dtype(self.spec.action_space)
        self._action_dtype = action_dtype
        self._action_pb_dtype = _DTYPE_TO_PB[action_dtype.name]
        self._stream: Stream | None = None
        self.closed = False

    def reset(self, env_indices: Sequence[int] = (), seeds: Sequence[int] = ()) -> pb.ResetResponse:
        """Reset instances (all when env_indices is empty); seeds as ResetRequest takes them."""
        request = pb.ResetRequest(session_id=self.session_id, env_indices=env_indices, seeds=seeds)
        return self._channel.call(self._channel.stub.Reset, request)

    def step(self, actions: Any) -> pb.StepResponse:
        """Step every instance with actions [B, ...]."""
        arr = np.ascontiguousarray(actions, self._action_dtype)
        action = pb.Tensor(dtype=self._action_pb_dtype, shape=arr.shape, data=arr.tobytes())
        if self._stream is None or not self._stream.open:
            self._stream = self._channel.open_stream(self._channel.stub.StepStream)
        return self._stream.call(pb.StepRequest(session_id=self.session_id, action=action))

    def render(self, env_indices: Sequence[int], width: int, height: int, camera: str) -> pb.RenderResponse:
        request = pb.RenderRequest(
            session_id=self.session_id, env_indices=env_indices, width=width, height=height, camera=camera
        )
        return self._channel.call(self._channel.stub.Render, request)

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
            if self._stream is not None:
                self._stream.close()
            self._channel.close()
