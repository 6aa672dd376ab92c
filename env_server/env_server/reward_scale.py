"""The Make kwarg every env takes, `reward_scale = {objective name: factor}`.

The session multiplies that objective's reward (and so its episode returns) by the
factor and reports it in the EnvSpec (`ObjectiveSpec.scale`, with min and max scaled),
so that any task's objective can be rescaled without editing the task.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from env_server.errors import InvalidArgument, quote
from env_server.task import Objective

#: The Make kwarg every env accepts: {objective name: factor}, applied by the session.
REWARD_SCALE = "reward_scale"


def check_reward_scale(value: Any) -> dict[str, float]:
    """`kwargs_json.reward_scale` as {name: factor}: a JSON object of finite numbers > 0
    (the names are checked against the env's objectives once it is built)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise InvalidArgument(
            f"kwargs_json.{REWARD_SCALE}: expected an object {{objective name: factor}}, got {quote(value)}"
        )
    factors = {}
    for name, factor in value.items():
        number = isinstance(factor, (int, float)) and not isinstance(factor, bool)
        if not (number and math.isfinite(factor) and factor > 0):
            raise InvalidArgument(
                f"kwargs_json.{REWARD_SCALE}.{quote(name)}: expected a finite number > 0, got {quote(factor)}"
            )
        factors[name] = float(factor)
    return factors


def scaled(objective: Objective, factor: float) -> Objective:
    """`objective` as reported after its reward is multiplied by `factor`."""
    return dataclasses.replace(
        objective,
        min=objective.min * factor,
        max=objective.max * factor,
        description=f"{objective.description} (reward x{factor:g})",
        scale=factor,
    )
