"""deploy/k8s/sweep: the sharded sweep's indexed Job, its merge Job and their scripts.

Rendered offline as test_deploy.py renders the base (deploy_manifests.py); without
kubectl on PATH the manifest tests are skipped, and the scripts run either way against
a stub agent. What is asserted: the sweep keeps the base's servers and drops its
training Job; the indexed Job, the merge Job and their scripts agree on the shard count,
folders and volume, and call real `agent sweep` flags; a shard starts its slice, then
resumes its folder after a restart; the merge waits for every shard.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess

import pytest
from deploy_manifests import (
    BASE,
    REPORT_SCRIPT,
    ROOT,
    SHARD_SCRIPT,
    SWEEP,
    Manifest,
    agent_flag_exists,
    container,
    env_server_of,
    env_value,
    mounted_file,
    needs_kubectl,
    one,
    render,
    secret_key,
)


@pytest.fixture(scope="module")
def base() -> list[Manifest]:
    return render(BASE)


@pytest.fixture(scope="module")
def server(base: list[Manifest]) -> tuple[Manifest, Manifest, argparse.Namespace]:
    return env_server_of(base)


@pytest.fixture(scope="module")
def sweep() -> list[Manifest]:
    return render(SWEEP)


def _sweep_jobs(text: str) -> int:
    """How many runs a sweep file makes (settings x seeds), as agent/src/sweep/file.rs counts them."""
    import tomllib

    cfg = tomllib.loads(text)
    settings = 1 if cfg["grid"].get("product") else 0
    for values in cfg["grid"].get("product", {}).values():
        settings *= values["linspace"][2] if isinstance(values, dict) else len(values)
    settings += len(cfg["grid"].get("points", []))
    return settings * len(cfg.get("seeds", [0]))


@needs_kubectl
def test_sweep_keeps_the_base_servers_and_drops_the_training_job(base, sweep) -> None:
    kept = [o for o in base if o["kind"] in ("Service", "StatefulSet")]
    assert kept == [o for o in sweep if o["kind"] in ("Service", "StatefulSet")]
    assert {o["metadata"]["name"] for o in sweep if o["kind"] == "Job"} == {"agent-sweep", "agent-sweep-report"}
    assert not [o for o in sweep if o["metadata"]["name"].startswith(("agent-runs", "agent-train", "agent-scripts"))]


@needs_kubectl
def test_sweep_job_runs_one_shard_per_completion_index_and_the_merge_waits_for_all(sweep, server) -> None:
    sts, _, server_args = server
    job, report = one(sweep, "Job", "agent-sweep"), one(sweep, "Job", "agent-sweep-report")
    spec, pod = job["spec"], job["spec"]["template"]["spec"]
    c, r = container(job, "agent"), container(report, "report")
    assert spec["completionMode"] == "Indexed"
    # N is written three times: the completions and both Jobs' SHARDS.
    shards = spec["completions"]
    assert int(env_value(c, "SHARDS")) == int(env_value(r, "SHARDS")) == shards
    assert 1 <= spec["parallelism"] <= shards
    assert env_value(c, "SWEEP_ROOT") == env_value(r, "SWEEP_ROOT")
    # Retries resume the shard: each is a new pod (the API's rule for these fields).
    assert pod["restartPolicy"] == "Never" and spec["backoffLimitPerIndex"] >= 1
    # ... and never beside the pod it replaces, which may still be writing the folder.
    assert spec["podReplacementPolicy"] == "Failed"
    assert pod["terminationGracePeriodSeconds"] >= 60
    # The scripts and the sweep from their ConfigMaps.
    for workload, cont, script in ((job, c, SHARD_SCRIPT), (report, r, REPORT_SCRIPT)):
        volume, key = mounted_file(workload, cont, cont["command"][-1])
        assert one(sweep, "ConfigMap", volume["configMap"]["name"])["data"][key] == script.read_text()
    volume, key = mounted_file(job, c, env_value(c, "SWEEP_CONFIG"))
    files = one(sweep, "ConfigMap", volume["configMap"]["name"])["data"]
    import tomllib

    sweep_file = tomllib.loads(files[key])
    assert sweep_file["base"] in files, "the sweep's base config is beside it in the ConfigMap"
    # Copies of the repository's configs (kustomize reads only files under its folder).
    assert files[key] == (ROOT / "configs" / "sweeps" / "dst-quick.toml").read_text().replace(
        'base = "../mompo/dst.toml"', 'base = "dst.toml"'
    )
    assert files[sweep_file["base"]] == (ROOT / "configs" / "mompo" / "dst.toml").read_text()
    assert _sweep_jobs(files[key]) >= shards, "agent sweep refuses more shards than jobs"
    # Every shard and the merge see one volume, which shards on several nodes share.
    claims = set()
    for workload, cont in ((job, c), (report, r)):
        volume, _ = mounted_file(workload, cont, env_value(cont, "SWEEP_ROOT") + "/x")
        claims.add(volume["persistentVolumeClaim"]["claimName"])
    (claim,) = claims
    assert one(sweep, "PersistentVolumeClaim", claim)["spec"]["accessModes"] == ["ReadWriteMany"]
    # The shards reach the servers as the training Job does.
    args = c["args"]
    for flag in (a for a in args if a.startswith("--")):
        assert agent_flag_exists(flag), f"agent sweep has no {flag}"
    assert args[args.index("--server") + 1] == f"dns:{sts['spec']['serviceName']}:{server_args.port}"
    assert secret_key(job, c, args[args.index("--tls-ca") + 1]) == ("env-server-ca", "ca.crt")
    assert secret_key(job, c, args[args.index("--token-file") + 1]) == ("agent-token", "token")
    for flag in ("--shard", "--resume", "--report", "--dir"):
        assert agent_flag_exists(flag), f"the scripts call agent sweep {flag}"


def _stub(tmp_path: pathlib.Path) -> tuple[pathlib.Path, pathlib.Path]:
    calls = tmp_path / "calls"
    stub = tmp_path / "agent-stub"
    stub.write_text(f'#!/bin/sh\nprintf "%s\\n" "$@" > {calls}\n')
    stub.chmod(0o755)
    return stub, calls


def test_sweep_shard_starts_its_slice_then_resumes_its_folder(tmp_path: pathlib.Path) -> None:
    stub, calls = _stub(tmp_path)
    root = tmp_path / "sweeps"
    server = ["--server", "dns:env-server:50051"]

    def run(**env: str) -> tuple[int, list[str] | None, str]:
        calls.unlink(missing_ok=True)
        done = subprocess.run(
            ["/bin/sh", str(SHARD_SCRIPT), *server],
            env={"PATH": os.environ["PATH"], "AGENT": str(stub), "SWEEP_ROOT": str(root), **env},
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
        return done.returncode, calls.read_text().splitlines() if calls.exists() else None, done.stderr

    folder = root / "shard-1-of-3"
    config = "/etc/agent/sweep/sweep.toml"
    start = ["sweep", "--config", config, "--shard", "1/3", "--dir", str(folder), *server]
    assert run(JOB_COMPLETION_INDEX="1", SHARDS="3")[:2] == (0, start)
    # A pod that died before the folder's sweep.json starts again; after it, pods resume.
    folder.mkdir(parents=True)
    assert run(JOB_COMPLETION_INDEX="1", SHARDS="3")[:2] == (0, start)
    (folder / "sweep.json").write_text("{}")
    resume = ["sweep", "--resume", str(folder), *server]
    assert run(JOB_COMPLETION_INDEX="1", SHARDS="3")[:2] == (0, resume)
    assert run(JOB_COMPLETION_INDEX="1", SHARDS="3", LEARNER_DEVICE="cuda")[1] == [*resume, "--device", "cuda"]
    code, called, err = run(SHARDS="3")
    assert code != 0 and called is None and "expected JOB_COMPLETION_INDEX" in err


def test_sweep_report_waits_for_every_shard_then_merges(tmp_path: pathlib.Path) -> None:
    import time

    stub, calls = _stub(tmp_path)
    root = tmp_path / "sweeps"
    folders = [root / f"shard-{i}-of-3" for i in range(3)]
    for folder in folders[:2]:
        folder.mkdir(parents=True)
        (folder / "summary.json").write_text("{}")
    proc = subprocess.Popen(
        ["/bin/sh", str(REPORT_SCRIPT)],
        env={"PATH": os.environ["PATH"], "AGENT": str(stub), "SWEEP_ROOT": str(root), "SHARDS": "3", "POLL_S": "0.1"},
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        time.sleep(1.0)
        assert proc.poll() is None and not calls.exists(), "merged before shard 2 finished"
        folders[2].mkdir(parents=True)
        (folders[2] / "summary.json").write_text("{}")
        assert proc.wait(30) == 0, proc.stderr.read()
    finally:
        proc.kill()
    assert calls.read_text().splitlines() == ["sweep", "--report", *map(str, folders), "--dir", str(root / "front")]


# ---------------------------------------------------------------------- container build files
