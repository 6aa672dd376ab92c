"""env_server: a batch-first gRPC server for multi-objective environments.

`python -m env_server` serves the Tasks in `env_server.envs.REGISTRY`, the prefix
adapters (`gym:`, `mo:`, `dmc:`) and any Task registered through the
`env_server.envs` entry-point group. `env_server.client` is the Python client.
"""

from env_server import gl as _gl

# Before mujoco or dm_control is imported: a headless OpenGL backend (or none), never a
# display; a MUJOCO_GL set by the user wins (see env_server/gl.py).
_gl.choose()

__version__ = "0.1.0"
