"""The committed stubs in env_server/_proto are exactly what scripts/gen_proto.sh generates."""

from __future__ import annotations

import filecmp
import os
import pathlib
import subprocess
import sys

PKG = pathlib.Path(__file__).resolve().parents[1]


def _files(root: pathlib.Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts)


def test_regenerated_stubs_match(tmp_path) -> None:
    env = dict(os.environ, PYTHON=sys.executable)
    subprocess.run(["bash", str(PKG / "scripts" / "gen_proto.sh"), str(tmp_path)], check=True, env=env)
    committed = PKG / "env_server" / "_proto"
    assert _files(tmp_path) == _files(committed)
    for name in _files(committed):
        assert filecmp.cmp(tmp_path / name, committed / name, shallow=False), name
