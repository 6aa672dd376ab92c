# syntax=docker/dockerfile:1
# env_server image: `python -m env_server` with the pinned simulators and the native gRPC
# front. Build from the repository root:
#
#   docker build -f deploy/docker/env_server.Dockerfile -t mo-mpo/env-server:latest .
#
# Pins: every Python package comes from requirements.lock (installed with it as the
# constraints file, so env_server's dependency closure gets exactly the locked versions,
# without torch, which only the agent needs); the native front is built by maturin (pinned
# in requirements.lock) against Cargo.lock (--locked). Python is the venv's 3.11.
ARG PYTHON_IMAGE=python:3.11.7-slim-bookworm
ARG RUST_IMAGE=rust:1.95.0-slim-bookworm

FROM ${RUST_IMAGE} AS rust

# ---------------------------------------------------------------- build: venv + native wheel
FROM ${PYTHON_IMAGE} AS build
RUN apt-get update \
 && apt-get install -y --no-install-recommends build-essential \
 && rm -rf /var/lib/apt/lists/*
# The Rust toolchain, from the official image of the same Debian release.
COPY --from=rust /usr/local/cargo /usr/local/cargo
COPY --from=rust /usr/local/rustup /usr/local/rustup
ENV RUSTUP_HOME=/usr/local/rustup CARGO_HOME=/usr/local/cargo PATH=/usr/local/cargo/bin:$PATH \
    PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1

WORKDIR /opt/mo-mpo
COPY requirements.lock ./
# The venv the runtime stage copies, at the same path. maturin goes to the build stage's
# own Python, not into the venv.
RUN python -m venv .venv \
 && .venv/bin/python -m pip install pip==25.3 \
 && python -m pip install -c requirements.lock maturin
COPY env_server/pyproject.toml env_server/README.md env_server/
# Dependencies first (a layer that changes only with the lock): env_server's declared
# dependencies and setuptools (its build backend), each at its requirements.lock version.
RUN .venv/bin/python -c "import tomllib; print('\n'.join(tomllib.load(open('env_server/pyproject.toml', 'rb'))['project']['dependencies']))" \
        > /tmp/env_server-deps.txt \
 && .venv/bin/python -m pip install -c requirements.lock -r /tmp/env_server-deps.txt setuptools

COPY . .
# The native front (env_server/native, a Rust extension) as a wheel, built like
# scripts/setup.sh builds it, against the venv's interpreter.
RUN --mount=type=cache,target=/usr/local/cargo/registry \
    cd env_server/native \
 && VIRTUAL_ENV=/opt/mo-mpo/.venv maturin build --release --locked \
        --interpreter /opt/mo-mpo/.venv/bin/python --out /tmp/wheels
# env_server itself as scripts/setup.sh installs it (its dependencies are in already), but
# not editable, and the native front's wheel.
RUN .venv/bin/python -m pip install -c requirements.lock --no-deps --no-build-isolation \
        ./env_server /tmp/wheels/env_server_native-*.whl \
 && .venv/bin/python -m pip check

# ---------------------------------------------------------------- runtime
FROM ${PYTHON_IMAGE}
# Mesa's software OpenGL for offscreen MuJoCo rendering (EGL, OSMesa; env_server/gl.py
# picks one), and libGL/glib that opencv-python (a robosuite dependency) loads on import.
RUN apt-get update \
 && apt-get install -y --no-install-recommends libegl1 libegl-mesa0 libosmesa6 libgl1 libglib2.0-0 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --uid 10001 --user-group --no-create-home --shell /usr/sbin/nologin envserver
COPY --from=build /opt/mo-mpo/.venv /opt/mo-mpo/.venv
ENV PATH=/opt/mo-mpo/.venv/bin:$PATH PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1
# Fails the build if a simulator, the TLS front or the health check cannot be imported.
RUN python -c "import env_server_native, env_server.server, env_server.tools.healthcheck, dm_control.suite, robosuite, gymnasium_robotics, mo_gymnasium" \
 && python -m env_server --list > /dev/null
USER 10001:10001
EXPOSE 50051
# Flags go after the image name (or in the pod's args): a non-loopback --host needs
# --tls-cert/--tls-key and --auth-token-file (or --insecure). deploy/k8s passes them.
ENTRYPOINT ["python", "-m", "env_server"]
CMD ["--help"]
