#!/usr/bin/env python3
"""Hard-link torch and its CUDA wheels from the project venv into the peers' venv.

    python scripts/peers/link_torch.py .venv .venv-peers scripts/peers/requirements.lock

torch 2.13.0 and the nvidia/cuda/triton wheels it pulls are about 4.5 GB; .venv
already has them at the versions the lock pins. Every file a distribution's RECORD
lists is hard-linked (as scripts/setup.sh's worktrees share .venv), so pip then finds
torch installed at its pin and downloads nothing. pip replaces files rather than
writing into them, so an uninstall or upgrade in .venv-peers never changes .venv.
A distribution .venv lacks, or has at another version, is left for pip to download.
"""

from __future__ import annotations

import os
import pathlib
import re
import sys

# torch's own large closure; the small pure-Python deps (sympy, jinja2...) pip fetches.
LINKED = re.compile(r"^(torch|triton|cuda-.*|nvidia-.*)$")


def site_packages(venv: pathlib.Path) -> pathlib.Path:
    found = sorted(venv.glob("lib/python3*/site-packages"))
    if len(found) != 1:
        raise SystemExit(f"{venv}: expected one lib/python3*/site-packages, found {len(found)}")
    return found[0]


def pins(lock: pathlib.Path) -> dict[str, str]:
    """name -> version of every `name==version` line whose name LINKED matches."""
    out = {}
    for line in lock.read_text().splitlines():
        name, sep, version = line.split("#")[0].strip().partition("==")
        if sep and LINKED.match(name.lower()):
            out[name.lower()] = version
    return out


def link(src: pathlib.Path, dst: pathlib.Path, name: str, version: str) -> bool:
    """Hard-link one distribution's files; False when src lacks it at `version`."""
    info = src / f"{re.sub(r'[-.]+', '_', name)}-{version}.dist-info"
    if not (info / "RECORD").exists():
        return False
    for row in (info / "RECORD").read_text().splitlines():
        rel = row.split(",")[0]
        if not rel or rel.startswith(".."):  # console scripts in bin/ carry .venv's path
            continue
        target = dst / rel
        if target.exists() or not (src / rel).exists():
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        os.link(src / rel, target)
    return True


def main() -> None:
    src_venv, dst_venv, lock = (pathlib.Path(a) for a in sys.argv[1:4])
    if not src_venv.exists():
        print(f"link_torch: no {src_venv}; pip downloads torch")
        return
    src, dst = site_packages(src_venv), site_packages(dst_venv)
    if src.parent.name != dst.parent.name:
        print(f"link_torch: {src.parent.name} != {dst.parent.name}; pip downloads torch")
        return
    linked = [f"{n}=={v}" for n, v in sorted(pins(lock).items()) if link(src, dst, n, v)]
    print(f"link_torch: hard-linked {len(linked)} distributions from {src_venv}")


if __name__ == "__main__":
    main()
