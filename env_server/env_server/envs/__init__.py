"""The shipped environments: one line per env id, sorted. Add a file here and a line below."""

from __future__ import annotations

from env_server.envs.dst import DeepSeaTreasure
from env_server.envs.humanoid_run import HumanoidRun
from env_server.task import Task

REGISTRY: dict[str, type[Task]] = {
    "dst": DeepSeaTreasure,
    "humanoid-run": HumanoidRun,
}
