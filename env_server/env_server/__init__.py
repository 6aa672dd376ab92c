"""env_server: a batch-first gRPC server for multi-objective environments.

`python -m env_server` serves the Tasks in `env_server.envs.REGISTRY`, the prefix
adapters (`gym:`, `mo:`, `dmc:`) and any Task registered through the
`env_server.envs` entry-point group. `env_server.client` is the Python client.
"""

import os as _os

# Headless by default: dm_control and mujoco otherwise try to open a display.
_os.environ.setdefault("MUJOCO_GL", "disable")

__version__ = "0.1.0"
