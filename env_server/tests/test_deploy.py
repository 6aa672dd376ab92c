"""deploy/: the Kubernetes manifests and the container build files.

No cluster runs here. The kustomizations are rendered with `kubectl kustomize` (kustomize
is built into kubectl) and the rendered YAML is turned into JSON by kubectl itself,
offline (`kubectl label --local ... -o json`, removing a label nobody sets), since PyYAML
is not in requirements.lock. Without kubectl on PATH the manifest tests are skipped.

What is asserted is what a deployment relies on and a typo would silently break: the
Service is headless and its port is the StatefulSet's container port and the probes'
port; the probes ask grpc.health.v1 over TLS (and the probe command works against a real
TLS server); the server's flags are real `python -m env_server` flags (parsed with its own
argparse builder, so renaming a flag fails here) and point at files of mounted Secrets;
the agent Job reaches the Service with `--server dns:NAME:PORT`; the GPU overlay asks for
a GPU and `--device cuda`; the Dockerfiles install from requirements.lock and keep the
agent's libtorch rpath valid.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import re
import subprocess
import sys

import pytest
from conftest import running_server
from deploy_manifests import (
    BASE,
    DOCKER,
    GPU,
    ROOT,
    SCRIPT,
    Manifest,
    agent_flag_exists,
    container,
    env_server_of,
    env_value,
    mounted_file,
    needs_kubectl,
    one,
    probe_args,
    render,
    secret_key,
)

from env_server.registry import Registry
from env_server.tools import devcerts, healthcheck


@pytest.fixture(scope="module")
def base() -> list[Manifest]:
    return render(BASE)


@pytest.fixture(scope="module")
def gpu() -> list[Manifest]:
    return render(GPU)


@pytest.fixture(scope="module")
def server(base: list[Manifest]) -> tuple[Manifest, Manifest, argparse.Namespace]:
    return env_server_of(base)


# ---------------------------------------------------------------------- env_server
@needs_kubectl
def test_service_is_headless_on_the_statefulsets_grpc_port(base, server) -> None:
    sts, c, args = server
    svc = one(base, "Service", sts["spec"]["serviceName"])
    assert svc["spec"]["clusterIP"] == "None"
    assert svc["spec"].get("publishNotReadyAddresses", False) is False
    assert svc["spec"]["selector"].items() <= sts["spec"]["template"]["metadata"]["labels"].items()
    (port,) = svc["spec"]["ports"]
    (cport,) = c["ports"]
    assert port["name"] == cport["name"] == "grpc"
    assert port["targetPort"] in (cport["name"], cport["containerPort"])
    # Headless: clients dial the pod addresses DNS returns, so the Service port must be the
    # port the server binds.
    assert port["port"] == cport["containerPort"] == args.port
    assert args.host == "0.0.0.0"


@needs_kubectl
def test_probes_ask_grpc_health_over_tls_on_the_served_port(base, server) -> None:
    sts, c, args = server
    svc_name = sts["spec"]["serviceName"]
    for kind in ("startupProbe", "readinessProbe", "livenessProbe"):
        probe = probe_args(c[kind])
        assert probe.port == args.port, kind
        assert probe.host == "127.0.0.1", kind
        # TLS verified with the CA kept beside the server's own certificate and key.
        assert secret_key(sts, c, probe.tls_ca) == (secret_key(sts, c, args.tls_cert)[0], "ca.crt"), kind
        assert probe.server_name == svc_name, kind
        assert c[kind]["timeoutSeconds"] > probe.timeout, f"{kind}: the kubelet would cut the check short"


@needs_kubectl
def test_server_flags_point_at_mounted_secrets(server) -> None:
    sts, c, args = server
    assert secret_key(sts, c, args.tls_cert) == ("env-server-tls", "tls.crt")
    assert secret_key(sts, c, args.tls_key) == ("env-server-tls", "tls.key")
    assert secret_key(sts, c, args.auth_token_file) == ("env-server-tokens", "tokens")
    assert not args.insecure
    for mount in c["volumeMounts"]:
        assert mount.get("readOnly") is True, mount


@needs_kubectl
def test_server_resources_match_its_instance_and_worker_limits(server) -> None:
    sts, c, args = server
    requests, limits = c["resources"]["requests"], c["resources"]["limits"]
    assert {"cpu", "memory"} <= requests.keys() and "memory" in limits
    assert "cpu" not in limits
    # One process per CPU requested: the server and the workers a session may start
    # (the flag's default, one per CPU the process sees, would be the node's count).
    assert args.max_workers == int(requests["cpu"]) - 1
    assert 1 <= args.max_envs_per_session <= args.max_live_envs
    memory_mib = int(requests["memory"].removesuffix("Gi")) * 1024
    # The sizing comment's arithmetic: ~420 MiB fixed plus ~49 MiB per instance (sawyer-peg).
    assert 420 + 49 * args.max_live_envs <= memory_mib + 64


def test_the_probe_command_answers_for_a_tls_server(tmp_path: pathlib.Path) -> None:
    """env_server.tools.healthcheck (the probes' command) against a real TLS server whose certificate
    names the Service, as the env-server-tls Secret's does."""
    certs = devcerts.write_all(tmp_path, ["env-server", "127.0.0.1"], ["learner"])
    tls = ["--tls-cert", str(certs["server.pem"]), "--tls-key", str(certs["server.key"])]
    with running_server(*tls, "--auth-token-file", str(certs["tokens"])) as address:
        port = address.rsplit(":", 1)[1]
        ca = ["--tls-ca", str(certs["ca.pem"])]
        assert healthcheck.main(["--port", port, *ca, "--server-name", "env-server"]) == 0
        assert healthcheck.main(["--port", port, *ca, "--server-name", "someone-else"]) == 1
        assert healthcheck.main(["--port", port]) == 1  # plaintext to a TLS server
    assert healthcheck.main(["--port", port, *ca, "--server-name", "env-server", "--timeout", "1"]) == 1


# ---------------------------------------------------------------------- agent
@needs_kubectl
def test_agent_job_reaches_the_headless_service_by_dns(base, server) -> None:
    sts, _, server_args = server
    svc = one(base, "Service", sts["spec"]["serviceName"])
    job = one(base, "Job", "agent-train")
    c = container(job, "agent")
    args = c["args"]
    for flag in (a for a in args if a.startswith("--")):
        assert agent_flag_exists(flag), f"agent train has no {flag}"
    server_addr = args[args.index("--server") + 1]
    match = re.fullmatch(r"dns:([a-z0-9.-]+):(\d+)", server_addr)
    assert match, server_addr
    host, port = match.groups()
    assert host == svc["metadata"]["name"] or host.startswith(svc["metadata"]["name"] + ".")
    assert int(port) == svc["spec"]["ports"][0]["port"] == server_args.port
    # TLS with the CA that signed the servers, and the learner's token, both from Secrets.
    assert secret_key(job, c, args[args.index("--tls-ca") + 1]) == ("env-server-ca", "ca.crt")
    assert secret_key(job, c, args[args.index("--token-file") + 1]) == ("agent-token", "token")


@needs_kubectl
def test_agent_job_restarts_into_its_run_on_a_volume(base) -> None:
    job = one(base, "Job", "agent-train")
    spec, pod = job["spec"], job["spec"]["template"]["spec"]
    assert pod["restartPolicy"] in ("Never", "OnFailure")
    assert spec["backoffLimit"] >= 1
    if "podFailurePolicy" in spec:
        assert pod["restartPolicy"] == "Never"  # the API's rule
    c = container(job, "agent")
    # The script from its ConfigMap, the run directory on the PVC.
    script_volume, script_key = mounted_file(job, c, c["command"][-1])
    scripts = one(base, "ConfigMap", script_volume["configMap"]["name"])
    assert scripts["data"][script_key] == SCRIPT.read_text(encoding="utf-8")
    runs_volume, _ = mounted_file(job, c, env_value(c, "RUNS_ROOT") + "/x")
    claim = one(base, "PersistentVolumeClaim", runs_volume["persistentVolumeClaim"]["claimName"])
    assert claim["spec"]["accessModes"] == ["ReadWriteOnce"]
    config_volume, config_key = mounted_file(job, c, env_value(c, "TRAIN_CONFIG"))
    config = one(base, "ConfigMap", config_volume["configMap"]["name"])
    assert config["data"][config_key] == (BASE / "agent" / "train.toml").read_text(encoding="utf-8")
    assert any(e["name"] == "JOB_NAME" and "fieldRef" in e["valueFrom"] for e in c["env"] if "valueFrom" in e)
    assert job["spec"]["template"]["spec"]["terminationGracePeriodSeconds"] >= 60  # the final checkpoint


@needs_kubectl
def test_train_config_fits_the_env_and_the_servers(base, server) -> None:
    sts, _, server_args = server
    job = one(base, "Job", "agent-train")
    c = container(job, "agent")
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+; env_server also supports 3.10
    cfg = tomllib.loads((BASE / "agent" / "train.toml").read_text(encoding="utf-8"))
    entry = Registry().resolve(cfg["env"]["id"])
    assert [o["name"] for o in cfg["learner"]["objectives"]] == [o.name for o in entry.objectives]
    assert "servers" not in cfg["env"]  # the Job's --server says where
    # Every replica gets at least one actor, and all sessions fit the servers' budget.
    replicas = sts["spec"]["replicas"]
    actors = cfg["env"]["num_actors"]
    assert actors >= replicas
    per_server = -(-actors // replicas) * cfg["env"]["num_envs"]
    assert per_server <= server_args.max_live_envs
    assert cfg["env"]["num_envs"] <= server_args.max_envs_per_session
    assert cfg["env"].get("workers", 0) <= server_args.max_workers
    assert cfg["learner"]["num_threads"] <= int(c["resources"]["requests"]["cpu"])


@needs_kubectl
def test_gpu_overlay_requests_a_gpu_and_cuda(base, gpu) -> None:
    c = container(one(gpu, "Job", "agent-train"), "agent")
    resources = c["resources"]
    assert str(resources["limits"]["nvidia.com/gpu"]) == "1"
    assert env_value(c, "LEARNER_DEVICE") == "cuda"
    assert re.search(r'--device "\$LEARNER_DEVICE"', SCRIPT.read_text(encoding="utf-8"))
    # `--device cuda` is a value of the agent's DeviceChoice (clap ValueEnum: lower case).
    config_rs = (ROOT / "agent" / "src" / "core" / "learner_config" / "mod.rs").read_text(encoding="utf-8")
    choices = re.search(r"pub enum DeviceChoice \{(.*?)\n\}", config_rs, re.S).group(1)
    assert re.search(r"^\s*Cuda,", choices, re.M)
    # Only the agent changes: the servers and everything else render as in the base.
    rest = [o for o in gpu if o["kind"] != "Job"]
    assert rest == [o for o in base if o["kind"] != "Job"]
    assert "nvidia.com/gpu" not in json.dumps(one(base, "Job", "agent-train"))


# ---------------------------------------------------------------------- train-or-resume.sh
def _run_script(tmp_path: pathlib.Path, runs: pathlib.Path, **env: str) -> tuple[int, list[str] | None]:
    calls = tmp_path / "calls"
    calls.unlink(missing_ok=True)
    stub = tmp_path / "agent-stub"
    stub.write_text(f'#!/bin/sh\nprintf "%s\\n" "$@" > {calls}\n')
    stub.chmod(0o755)
    done = subprocess.run(
        ["/bin/sh", str(SCRIPT), "--server", "dns:env-server:50051"],
        env={
            "PATH": os.environ["PATH"],
            "AGENT": str(stub),
            "RUNS_ROOT": str(runs),
            "JOB_NAME": "job-a",
            "TRAIN_CONFIG": "/etc/agent/config/train.toml",
            **env,
        },
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    return done.returncode, calls.read_text().splitlines() if calls.exists() else None


def test_train_or_resume_starts_resumes_and_stops(tmp_path: pathlib.Path) -> None:
    runs = tmp_path / "runs"
    job_runs = runs / "job-a"
    server = ["--server", "dns:env-server:50051"]
    new = ["train", "--config", "/etc/agent/config/train.toml", "--set", f'run.runs_dir="{job_runs}"', *server]

    assert _run_script(tmp_path, runs) == (0, new)
    # A pod that died before its first checkpoint left a directory: start afresh.
    (job_runs / "humanoid-run__mompo__0__20231114-221320").mkdir(parents=True)
    assert _run_script(tmp_path, runs) == (0, new)
    # The newest run with a checkpoint is resumed, with the same flags.
    for stamp in ("20231114-221320-2", "20231115-080000"):
        (job_runs / f"humanoid-run__mompo__0__{stamp}" / "checkpoints").mkdir(parents=True)
        (job_runs / f"humanoid-run__mompo__0__{stamp}" / "checkpoints" / "latest.json").write_text("{}")
    newest = job_runs / "humanoid-run__mompo__0__20231115-080000"
    assert _run_script(tmp_path, runs) == (0, ["train", "--resume", str(newest), *server])
    assert _run_script(tmp_path, runs, LEARNER_DEVICE="cuda") == (
        0,
        ["train", "--resume", str(newest), *server, "--device", "cuda"],
    )
    # An interrupted run (SIGTERM) is resumed; a finished one is left alone.
    (newest / "summary.json").write_text('{\n  "interrupted": "SIGTERM"\n}')
    assert _run_script(tmp_path, runs)[1] == ["train", "--resume", str(newest), *server]
    (newest / "summary.json").write_text('{\n  "eval_return": [1.0],\n  "interrupted": null,\n  "eval_video": null\n}')
    assert _run_script(tmp_path, runs) == (0, None)
    # Another Job's runs are its own.
    assert _run_script(tmp_path, runs, JOB_NAME="job-b")[1][:2] == ["train", "--config"]


def _python_minor() -> str:
    return f"{sys.version_info.major}.{sys.version_info.minor}"


@pytest.mark.parametrize("name", ["env_server.Dockerfile", "agent.Dockerfile"])
def test_dockerfiles_install_from_the_lockfiles(name: str) -> None:
    text = (DOCKER / name).read_text(encoding="utf-8")
    assert "COPY requirements.lock ./" in text
    installs = [line for line in text.splitlines() if "pip install" in line]
    # Every package install is constrained by the lock (pip itself is pinned as setup.sh pins it).
    setup_pip = re.search(r"pip install [^\n]*(pip==[\d.]+)", (ROOT / "scripts" / "setup.sh").read_text()).group(1)
    for line in installs:
        assert "-c requirements.lock" in line or line.rstrip(" \\").endswith(f"pip install {setup_pip}"), line
    # The Python of the images is the venv's.
    (image,) = re.findall(r"^ARG PYTHON_IMAGE=python:(\d+\.\d+)", text, re.M)
    assert image == _python_minor()
    assert "--locked" in text  # Cargo.lock


def test_agent_image_keeps_the_libtorch_rpath_valid() -> None:
    text = (DOCKER / "agent.Dockerfile").read_text(encoding="utf-8")
    assert "cargo build --release --locked -p agent" in text
    # .cargo/config.toml finds <repo root>/.venv: the build stage's root is /opt/mo-mpo ...
    stages = re.split(r"^FROM ", text, flags=re.M)
    build = next(s for s in stages if s.startswith("${PYTHON_IMAGE} AS build"))
    assert "WORKDIR /opt/mo-mpo\n" in build and "python -m venv .venv" in build
    assert 'VIRTUAL_ENV = { value = ".venv", relative = true' in (ROOT / ".cargo" / "config.toml").read_text()
    # ... the binary's rpath is checked to be that venv's torch/lib, and the runtime stage
    # has the venv at the same path.
    assert f"readelf -d /opt/mo-mpo/bin/agent | grep -F /opt/mo-mpo/.venv/lib/python{_python_minor()}/" in build
    assert "COPY --from=build /opt/mo-mpo/.venv /opt/mo-mpo/.venv" in stages[-1]
    assert "RUN agent --version" in stages[-1]


def test_env_server_image_runs_the_server_and_its_probe() -> None:
    text = (DOCKER / "env_server.Dockerfile").read_text(encoding="utf-8")
    assert "maturin build --release --locked" in text
    assert 'ENTRYPOINT ["python", "-m", "env_server"]' in text
    assert "env_server.tools.healthcheck" in text  # imported at build time
    assert "USER 10001:10001" in text


def test_dockerignore_keeps_local_builds_out_of_the_context() -> None:
    ignored = set((ROOT / ".dockerignore").read_text(encoding="utf-8").split())
    assert {".git", ".venv", "target", "runs", "certs"} <= ignored
