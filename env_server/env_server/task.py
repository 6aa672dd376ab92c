"""The Task contract: one environment instance with a named vector reward.

Every shipped env and every adapter (gymnasium, MO-Gymnasium, dm_control,
robosuite) implements this; the server only ever talks to Tasks. A Task knows
nothing of gRPC, sessions or batching: the server owns B Tasks per session.

Objectives are declared once, on the class, as a tuple of `Objective`; the
reward returned by `step` has exactly one entry per objective, in that order.

Task docstrings carry a `## Reward Space` section (MO-Gymnasium's convention), one
line per reward entry: `<index>: <name>, <definition>, <range>`. Nothing parses it:
`objectives` is the declaration the server serves, and the section is where a reader
finds each formula and its units, so it keeps the same names in the same order.
docs/adding-an-env.md walks through writing a Task.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import Any, ClassVar

import gymnasium
import numpy as np

from env_server.errors import FailedPrecondition

# Declared here for Task authors (`from env_server.task import Objective`); defined in
# shared.py, which the client imports without the server.
from env_server.shared import ClosedForm as ClosedForm
from env_server.shared import Objective as Objective


def action_norm_bounds(action_space: gymnasium.spaces.Box) -> tuple[float, float]:
    """(min, max) of -||a||_2 over a Box: the bounds an `ACTION_NORM` objective declares."""
    low, high = np.asarray(action_space.low, np.float64).ravel(), np.asarray(action_space.high, np.float64).ravel()
    largest = np.maximum(np.abs(low), np.abs(high))
    holds_zero = (low <= 0) & (high >= 0)
    nearest = np.where(holds_zero, 0.0, np.minimum(np.abs(low), np.abs(high)))
    # + 0.0: a Box that holds zero gives max 0, not -0.
    return -math.sqrt(float(np.sum(largest**2))) + 0.0, -math.sqrt(float(np.sum(nearest**2))) + 0.0


@dataclasses.dataclass
class StepOutcome:
    """What one instance returns from one step."""

    observation: Any
    reward: np.ndarray  # float [K], in Task.objectives order
    terminated: bool
    truncated: bool
    info: dict[str, Any] = dataclasses.field(default_factory=dict)


class Task(abc.ABC):
    """One environment instance.

    Subclasses set the class attributes (or, for adapters whose objectives depend
    on the wrapped env, instance attributes in __init__) and implement reset/step.
    Constructor keyword arguments come from MakeRequest.kwargs_json.
    """

    #: One line for `--list` and ListEnvs.
    description: ClassVar[str] = ""
    #: The K objectives, in reward order.
    objectives: tuple[Objective, ...] = ()
    #: Time limit applied by the server (truncation); None = no limit.
    max_episode_steps: int | None = None
    #: Info keys this task can report each step (numeric scalars or arrays).
    info_keys: tuple[str, ...] = ()
    #: Named cameras `render` accepts besides "" (the task's default view).
    cameras: tuple[str, ...] = ()
    #: Frames per second that play the task in real time (1 / control period); 0 = unknown.
    render_fps: float = 0.0

    observation_space: gymnasium.spaces.Space
    action_space: gymnasium.spaces.Space

    @abc.abstractmethod
    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        """Start an episode; a given seed makes it reproducible."""

    @abc.abstractmethod
    def step(self, action: Any) -> StepOutcome:
        """Advance one step. The action has already been validated against action_space."""

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        """The current frame as uint8 [height, width, 3] RGB, top row first.

        `camera` is "" (a view that shows the task) or one of `cameras`; the server has
        checked it and the size. A Task without frames does not override this, and
        Render on it is FAILED_PRECONDITION (the session checks before calling; this
        answer is for direct callers). Renderers that need OpenGL call
        `env_server.gl.require()` first, so a server without it says what to install.
        """
        raise FailedPrecondition(f"task {type(self).__name__} has no renderer (Task.render)")

    def close(self) -> None:
        """Release simulator resources."""
