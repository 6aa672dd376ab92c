"""Mocap clip support for humanoid-mocap: the dm_control loader fix and clip I/O.

The shipped clips (`clips/synthetic_lying.h5`) are SYNTHETIC: physics rollouts of
dm_control's CMU humanoid, recorded by `env_server/tools/make_clips.py`. They are NOT CMU motion capture
data. To track the real CMU database, download dm_control's `cmu_2020_*.h5` (it cannot be
downloaded on the build machines) and pass `clip_path=...` (and `clip_ids=...`) to the task.
"""

from __future__ import annotations

import os

import numpy as np

#: The clips shipped in the package (synthetic, not CMU data).
SHIPPED_CLIPS = os.path.join(os.path.dirname(__file__), "clips", "synthetic_lying.h5")
#: Extra per-clip dataset (not part of dm_control's format, ignored by its loader): the
#: normalized actions ([-1, 1], the task's action space) that recorded the clip.
ACTIONS_KEY = "env_server_actions"

_PATCHED = False


def patch_loader() -> None:
    """Make dm_control 1.0.28's HDF5 mocap loader work with protobuf >= 7.

    The loader calls FieldDescriptor.label, which protobuf 7 removed (grpcio-tools forces
    protobuf 7). This replaces the one method that uses it; idempotent.
    """
    global _PATCHED
    if _PATCHED:
        return
    from dm_control.locomotion.mocap import loader
    from google.protobuf import descriptor

    def _fill_primitive_proto_fields(self, proto, h5_group, skip_fields=()):
        for field in proto.DESCRIPTOR.fields:
            if field.name in skip_fields or field.name not in h5_group.attrs:
                continue
            if field.type in (descriptor.FieldDescriptor.TYPE_GROUP, descriptor.FieldDescriptor.TYPE_MESSAGE):
                continue
            if hasattr(field, "is_repeated"):
                repeated = field.is_repeated
            else:  # protobuf < 7
                repeated = field.label == descriptor.FieldDescriptor.LABEL_REPEATED
            if repeated:
                getattr(proto, field.name).extend(h5_group.attrs[field.name])
            else:
                setattr(proto, field.name, h5_group.attrs[field.name])

    loader.HDF5TrajectoryLoader._fill_primitive_proto_fields = _fill_primitive_proto_fields
    _PATCHED = True


FEATURE_KEYS = (
    "angular_velocity",
    "appendages",
    "body_positions",
    "body_quaternions",
    "center_of_mass",
    "end_effectors",
    "joints",
    "joints_velocity",
    "position",
    "quaternion",
    "velocity",
)


def write_clip(h5file, clip_id: str, dt: float, frames: list[dict], actions: np.ndarray | None = None) -> None:
    """Write one clip in dm_control's HDF5 layout from `reference_pose.utils.get_features` dicts.

    Each dataset is (D, T) float64 under `<clip_id>/walkers/walker_0`, as the loader expects.
    """
    grp = h5file.create_group(clip_id)
    grp.attrs["num_steps"] = len(frames)
    grp.attrs["dt"] = dt
    grp.create_group("props")
    walker = grp.create_group("walkers/walker_0")
    walker.attrs["name"] = b"synthetic_CMU_humanoid"
    walker.attrs["model"] = 1  # CMU_2019: dm_control's default CMU humanoid
    walker.attrs["mass"] = 0.0
    walker.attrs["end_effector_names"] = np.array([], dtype="S1")
    walker.attrs["appendage_names"] = np.array([], dtype="S1")
    walker.create_group("scaling")
    walker.create_group("markers")
    for key in FEATURE_KEYS:
        data = np.stack([np.asarray(f[key], np.float64).reshape(-1) for f in frames], axis=1)
        walker.create_dataset(key, data=data, compression="gzip")
    if actions is not None:
        grp.create_dataset(ACTIONS_KEY, data=np.asarray(actions, np.float64), compression="gzip")
