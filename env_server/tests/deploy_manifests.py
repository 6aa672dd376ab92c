"""What the deploy tests share: where deploy/ lives, rendering a kustomization to JSON
with kubectl (offline), finding objects, containers, mounted files and env values in
it, and whether the server and the agent take the flags a manifest gives them."""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import re
import shutil
import subprocess
from typing import Any

import pytest

from env_server.__main__ import _parser as server_parser
from env_server.tools import healthcheck

ROOT = pathlib.Path(__file__).resolve().parents[2]
K8S = ROOT / "deploy" / "k8s"
DOCKER = ROOT / "deploy" / "docker"
BASE = K8S / "base"
GPU = K8S / "overlays" / "gpu"
SCRIPT = BASE / "agent" / "train-or-resume.sh"
SWEEP = K8S / "sweep"
SHARD_SCRIPT = SWEEP / "agent" / "sweep-shard.sh"
REPORT_SCRIPT = SWEEP / "agent" / "sweep-report.sh"

KUBECTL = shutil.which("kubectl")
needs_kubectl = pytest.mark.skipif(KUBECTL is None, reason="kubectl (with its built-in kustomize) is not on PATH")

Manifest = dict[str, Any]


def _kubectl(*args: str, stdin: str | None = None) -> str:
    # No cluster is contacted: kustomize reads files, and label --local edits what it is given.
    env = {**os.environ, "KUBECONFIG": os.devnull}
    done = subprocess.run(
        [KUBECTL, *args], input=stdin, capture_output=True, text=True, timeout=120, env=env, check=False
    )
    assert done.returncode == 0, f"kubectl {' '.join(args)} failed: {done.stderr}"
    return done.stdout


def render(path: pathlib.Path) -> list[Manifest]:
    """Every object `kubectl kustomize path` renders, as JSON-decoded dicts."""
    rendered = _kubectl("kustomize", str(path))
    text = _kubectl("label", "--local", "-f", "-", "-o", "json", "mo-mpo-render-test-", stdin=rendered)
    decoder, objects, at = json.JSONDecoder(), [], 0
    while True:
        while at < len(text) and text[at].isspace():
            at += 1
        if at == len(text):
            break
        obj, at = decoder.raw_decode(text, at)
        objects.extend(obj["items"] if obj.get("kind") == "List" else [obj])
    assert len(objects) == rendered.count("\nkind: ") + rendered.startswith("kind: "), "an object was lost"
    return objects


def one(objects: list[Manifest], kind: str, name: str | None = None) -> Manifest:
    found = [o for o in objects if o["kind"] == kind and (name is None or o["metadata"]["name"] == name)]
    assert len(found) == 1, f"expected one {kind} {name or ''}, got {[o['metadata']['name'] for o in found]}"
    return found[0]


def container(workload: Manifest, name: str) -> Manifest:
    return next(c for c in workload["spec"]["template"]["spec"]["containers"] if c["name"] == name)


def mounted_file(workload: Manifest, c: Manifest, path: str) -> tuple[Manifest, str]:
    """The pod volume that holds file `path` in container `c`, and the file's key in it."""
    for mount in c.get("volumeMounts", []):
        prefix = mount["mountPath"].rstrip("/") + "/"
        if path.startswith(prefix):
            volumes = workload["spec"]["template"]["spec"]["volumes"]
            volume = next(v for v in volumes if v["name"] == mount["name"])
            return volume, path[len(prefix) :]
    raise AssertionError(f"{path} is under no volume mount of container {c['name']}")


def secret_key(workload: Manifest, c: Manifest, path: str) -> tuple[str, str]:
    volume, key = mounted_file(workload, c, path)
    assert "secret" in volume, f"{path} is in volume {volume['name']}, expected a Secret volume"
    return volume["secret"]["secretName"], key


def env_value(c: Manifest, name: str) -> str | None:
    for item in c.get("env", []):
        if item["name"] == name:
            return item.get("value")
    return None


def parse_server_args(args: list[str]) -> argparse.Namespace:
    try:
        return server_parser().parse_args(args)
    except SystemExit as exc:  # argparse exits on an unknown or malformed flag
        raise AssertionError(f"`python -m env_server` refuses the manifest's args {args}") from exc


def env_server_of(objects: list[Manifest]) -> tuple[Manifest, Manifest, argparse.Namespace]:
    """The env_server StatefulSet, its container, and its args as the server parses them."""
    sts = one(objects, "StatefulSet", "env-server")
    c = container(sts, "env-server")
    return sts, c, parse_server_args(c["args"])


def probe_args(probe: Manifest) -> argparse.Namespace:
    command = probe["exec"]["command"]
    assert command[:3] == ["python", "-m", "env_server.tools.healthcheck"], command
    try:
        return healthcheck._parser().parse_args(command[3:])
    except SystemExit as exc:
        raise AssertionError(f"env_server.tools.healthcheck refuses the probe's args {command}") from exc


# The agent's command line: main.rs and cli/ (a module per subcommand, cli/args.rs the
# flags several share).
AGENT_MAIN = "\n".join(
    path.read_text(encoding="utf-8")
    for path in [ROOT / "agent" / "src" / "main.rs", *sorted((ROOT / "agent" / "src" / "cli").glob("*.rs"))]
)


def agent_flag_exists(flag: str) -> bool:
    """Whether the agent's command line declares `--flag` (clap derive: `long = "flag"`, or a
    `#[arg(long...)]` field named like it)."""
    name = flag.removeprefix("--")
    field = name.replace("-", "_")
    # The attribute ends at its line's `)]` (its own lists, e.g. conflicts_with_all = [..], hold `]`).
    # A field may carry a visibility (`pub(crate) device:` in a shared flag struct).
    return f'long = "{name}"' in AGENT_MAIN or re.search(
        rf"#\[arg\(long[^\n]*\)\]\s*(?:///.*\s*)*(?:pub(?:\([^)]*\))?\s+)?{field}:", AGENT_MAIN
    )
