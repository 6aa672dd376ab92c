"""The shipped environments: one line per env id, sorted. Add a file here, a line below
and the id in `shared.SHIPPED_ENV_IDS` (the client's copy, which imports no env).

Each file's docstring documents its task with `## Observation`, `## Action` and
`## Reward Space` sections (the convention is explained in env_server/task.py).
"""

from __future__ import annotations

from env_server.envs.dst import DeepSeaTreasure
from env_server.envs.humanoid_mocap import HumanoidMocap
from env_server.envs.humanoid_run import HumanoidRun
from env_server.envs.pendulum import Pendulum
from env_server.envs.sawyer_peg import SawyerPeg
from env_server.envs.shadow_orient import ShadowOrient
from env_server.envs.shadow_touch import ShadowTouch
from env_server.envs.shadow_turn import ShadowTurn
from env_server.task import Task

REGISTRY: dict[str, type[Task]] = {
    "dst": DeepSeaTreasure,
    "humanoid-mocap": HumanoidMocap,
    "humanoid-run": HumanoidRun,
    "pendulum": Pendulum,
    "sawyer-peg": SawyerPeg,
    "shadow-orient": ShadowOrient,
    "shadow-touch": ShadowTouch,
    "shadow-turn": ShadowTurn,
}
