"""Numpy and session types as mo_env.v1 protobuf: tensors, spaces, specs, Reset and Step results.

No grpc here (server.py owns the transport). Tensors travel as the raw bytes of numpy
buffers, so the host must be little-endian like the wire format.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from env_server import shared, spaces
from env_server._proto.mo_env.v1 import env_pb2 as pb
from env_server.results import ResetResult, StepResult
from env_server.session import Session
from env_server.task import ClosedForm, Objective

if sys.byteorder != "little":
    raise ImportError("env_server sends native numpy buffers as little-endian tensors; this host is big-endian")

DTYPE_TO_PB = {
    "float32": pb.DTYPE_FLOAT32,
    "float64": pb.DTYPE_FLOAT64,
    "int32": pb.DTYPE_INT32,
    "int64": pb.DTYPE_INT64,
    "uint8": pb.DTYPE_UINT8,
    "bool": pb.DTYPE_BOOL,
}
PB_TO_DTYPE = {v: k for k, v in DTYPE_TO_PB.items()}


def tensor(arr: np.ndarray) -> pb.Tensor:
    return pb.Tensor(dtype=DTYPE_TO_PB[arr.dtype.name], shape=arr.shape, data=arr.tobytes())


def named(leaves: list[tuple[Any, np.ndarray]]) -> list[pb.NamedTensor]:
    return [pb.NamedTensor(name=getattr(leaf, "name", leaf), tensor=tensor(arr)) for leaf, arr in leaves]


def space_to_pb(spec: dict[str, Any]) -> pb.Space:
    """A shared.space_to_spec dict as a protobuf Space."""
    if "dict" in spec:
        return pb.Space(
            dict=pb.DictSpace(entries=[pb.NamedSpace(name=k, space=space_to_pb(s)) for k, s in spec["dict"]])
        )
    if "discrete" in spec:
        return pb.Space(discrete=pb.DiscreteSpace(n=spec["discrete"]["n"], start=spec["discrete"]["start"]))
    box = spec["box"]
    return pb.Space(
        box=pb.BoxSpace(dtype=DTYPE_TO_PB[box["dtype"]], shape=box["shape"], low=box["low"], high=box["high"])
    )


#: Objective.closed_form on the wire (and back: `remote.objectives`).
CLOSED_FORM_TO_PB = {
    ClosedForm.NONE: pb.CLOSED_FORM_NONE,
    ClosedForm.ACTION_NORM: pb.CLOSED_FORM_ACTION_NORM,
    ClosedForm.UNDECLARED: pb.CLOSED_FORM_UNSPECIFIED,
}


def objectives_pb(objectives: tuple[Objective, ...]) -> list[pb.ObjectiveSpec]:
    return [
        pb.ObjectiveSpec(
            name=o.name,
            description=o.description,
            min=o.min,
            max=o.max,
            scale=o.scale,
            closed_form=CLOSED_FORM_TO_PB[o.closed_form],
        )
        for o in objectives
    ]


def spec_pb(session: Session) -> pb.EnvSpec:
    spec = session.spec
    return pb.EnvSpec(
        env_id=spec.env_id,
        num_envs=spec.num_envs,
        observation_space=space_to_pb(shared.space_to_spec(spec.observation_space)),
        action_space=space_to_pb(shared.space_to_spec(spec.action_space)),
        objectives=objectives_pb(spec.objectives),
        max_episode_steps=spec.max_episode_steps,
        autoreset_mode=int(spec.autoreset),
        discount=spec.discount,
        info_keys=spec.info_keys,
    )


def reset_pb(result: ResetResult) -> pb.ResetResponse:
    return pb.ResetResponse(observation=named(result.observation), info=named(result.info))


def _prefix(message: pb.StepResponse, data_bytes: int) -> bytes:
    """The encoding of a one-field message whose last `data_bytes` bytes are its array."""
    raw = message.SerializeToString()
    return raw[: len(raw) - data_bytes]


class StepEncoder:
    """Serialized StepResponses for one session, without building a message per Step.

    A session's observation, reward and done flags keep their dtypes and shapes at every
    Step, so their encoding is fixed framing around the bytes of the session's buffers:
    protobuf computes the framing once, from zero-filled arrays, and each Step joins it
    with the buffers (a packed bool is one byte, 0 or 1, like a numpy bool). The fields
    that vary in size (info, episodes, final observations; 5-7, after 1-4 as protobuf
    orders them) are rare and left to protobuf, so the bytes are exactly what a
    StepResponse built from the same result serializes to.
    """

    def __init__(self, leaves: Sequence[spaces.Leaf], num_envs: int, num_objectives: int) -> None:
        self._framing: list[bytes] = []
        for leaf in leaves:
            zeros = np.zeros((num_envs, *leaf.shape), leaf.dtype)
            self._framing.append(_prefix(pb.StepResponse(observation=named([(leaf, zeros)])), zeros.nbytes))
        reward = np.zeros((num_envs, num_objectives), np.float32)
        self._framing.append(_prefix(pb.StepResponse(reward=tensor(reward)), reward.nbytes))
        self._framing.append(_prefix(pb.StepResponse(terminated=[False] * num_envs), num_envs))
        self._framing.append(_prefix(pb.StepResponse(truncated=[False] * num_envs), num_envs))

    def encode(self, result: StepResult) -> bytes:
        arrays = [arr for _, arr in result.observation]
        arrays += (result.reward, result.terminated, result.truncated)
        parts: list[Any] = [part for pair in zip(self._framing, arrays) for part in pair]
        if result.info or result.episodes:
            parts.append(_varying_pb(result).SerializeToString())
        return b"".join(parts)


def _varying_pb(result: StepResult) -> pb.StepResponse:
    return pb.StepResponse(
        info=named(result.info),
        episodes=[
            pb.EpisodeEnd(
                env_index=e.env_index,
                episode_return=e.episode_return.tolist(),
                discounted_return=e.discounted_return.tolist(),
                length=e.length,
                terminated=e.terminated,
                truncated=e.truncated,
            )
            for e in result.episodes
        ],
        final_observation=named(result.final_observation),
    )
