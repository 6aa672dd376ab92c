"""Generate the shipped SYNTHETIC mocap clips (not CMU data): physics rollouts of the CMU humanoid.

    python -m env_server.tools.make_clips [--out PATH]

1. A kinematic bootstrap clip (the humanoid lying still on the floor in the zero pose; a
   position-controlled humanoid without a balance controller cannot stand, it collapses)
   is written to a temporary file. It only sets up a tracking environment identical to the
   one humanoid-mocap builds (same walker, arena, physics and control timesteps).
2. In that environment, position targets follow a smooth pose sequence: every joint moves
   from the zero pose towards 80 % of one of its limits and back over 3 s
   ("synthetic_curl": the limit of larger magnitude, "synthetic_stretch": the other one). The physics is stepped, and after every control step
   `reference_pose.utils.get_features` records the walker's features, as dm_control's own
   clips store them.
3. A rollout is cut if the root height ever changes by more than 30 cm (it does not: the
   body stays on the floor, although it may roll) and ends at 100 frames (3 s). It is written in dm_control's HDF5 layout, with the
   normalized actions that produced it (dataset `env_server_actions`), so a test can replay
   it exactly.

Deterministic: the same code and versions give the same file.
"""

from __future__ import annotations

import argparse
import os
import tempfile

import h5py
import numpy as np

from env_server.mocap import SHIPPED_CLIPS, write_clip

DT = 0.03  # control timestep of the clips (dm_control's CMU clips use 0.03)
FRAMES = 100


def _standing_features(n: int) -> tuple[list[dict], float]:
    """Features of the zero pose, upright, feet touching the floor, repeated n times."""
    from dm_control import mjcf
    from dm_control.locomotion import arenas, walkers
    from dm_control.locomotion.tasks.reference_pose import utils

    walker = walkers.CMUHumanoidPositionControlled()
    arena = arenas.Floor()
    arena.add_free_entity(walker)
    physics = mjcf.Physics.from_mjcf_model(arena.mjcf_model)
    # The CMU model is y-up: the identity root quaternion lays it on the floor. A position-
    # controlled humanoid without a balance controller cannot stand (it collapses within
    # 0.3 s), so the clips are recorded lying on the floor, where the physics is stable.
    upright = [1.0, 0.0, 0.0, 0.0]
    lo, hi = 0.0, 1.5
    for _ in range(40):  # bisect the root height at which the feet first touch the floor
        mid = 0.5 * (lo + hi)
        physics.bind(walker.mocap_joints).qpos = 0.0
        walker.set_pose(physics, position=[0, 0, mid], quaternion=upright)
        physics.forward()
        if physics.data.ncon > 0:
            lo = mid
        else:
            hi = mid
    walker.set_pose(physics, position=[0, 0, hi + 1e-4], quaternion=upright)
    physics.forward()
    features = utils.get_features(physics, walker)
    return [features] * n, hi + 1e-4


def _targets(kind: str, t: float, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Joint targets (actuator order) at time t: from the zero pose towards a far pose and back.

    "curl": every joint towards 80 % of its limit of larger magnitude; "stretch": towards 80 %
    of the other limit. Large whole-body motions, so that a policy that does not track (for
    example the zero action) exceeds the termination error.
    """
    far = np.where(np.abs(high) >= np.abs(low), high, low)
    if kind == "stretch":
        far = np.where(np.abs(high) >= np.abs(low), low, high)
    blend = 0.5 * (1.0 - np.cos(2.0 * np.pi * t / 2.4))  # 0 -> 1 -> 0 over 3 s
    return 0.8 * blend * far


def record(kind: str, bootstrap_path: str, bootstrap_id: str) -> tuple[list[dict], np.ndarray]:
    from dm_control.locomotion.tasks.reference_pose import utils

    from env_server.envs.humanoid_mocap import HumanoidMocap

    task = HumanoidMocap(clip_path=bootstrap_path, clip_ids=[bootstrap_id], min_steps=FRAMES + 10)
    task.task._termination_error_threshold = 1e9  # recording: never stop on the bootstrap clip
    task.reset(seed=0)
    physics, walker = task.env.physics, task.task._walker
    low, high = task._ctrl_low, task._ctrl_low + 2 * task._ctrl_half  # joint ranges, actuator order
    frames = [utils.get_features(physics, walker)]
    z0 = frames[0]["position"][2]
    actions = []
    for t in range(FRAMES - 1):
        action = task.action_from_ctrl(_targets(kind, (t + 1) * DT, low, high))
        actions.append(action)
        task.step(action)
        feat = utils.get_features(physics, walker)
        if abs(feat["position"][2] - z0) > 0.3:  # cut if the body ever leaves the floor
            break
        frames.append(feat)
    actions = np.array(actions[: len(frames) - 1])
    return frames, actions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=SHIPPED_CLIPS)
    args = parser.parse_args()
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        boot = os.path.join(tmp, "bootstrap.h5")
        frames, _ = _standing_features(FRAMES + 40)
        with h5py.File(boot, "w") as f:
            write_clip(f, "bootstrap_standing", DT, frames)
        with h5py.File(args.out, "w") as f:
            f.attrs["note"] = "SYNTHETIC physics rollouts of the dm_control CMU humanoid; NOT CMU motion capture data"
            for kind in ("curl", "stretch"):
                frames, actions = record(kind, boot, "bootstrap_standing")
                write_clip(f, f"synthetic_{kind}", DT, frames, actions)
                print(f"synthetic_{kind}: {len(frames)} frames")
    print(f"wrote {args.out} ({os.path.getsize(args.out) / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
