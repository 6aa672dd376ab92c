# syntax=docker/dockerfile:1
# agent image: the `agent` binary and the libtorch it links. Build from the repository root:
#
#   docker build -f deploy/docker/agent.Dockerfile -t mo-mpo/agent:latest .
#
# The agent links libtorch from the torch wheel pinned in requirements.lock (tch 0.26 needs
# torch 2.13.0), dynamically, with an rpath to the wheel's torch/lib (agent/build.rs). So
# the build stage makes the venv at /opt/mo-mpo/.venv, where .cargo/config.toml finds it
# (the repository root is /opt/mo-mpo), and the runtime stage copies it to the same path:
# the rpath baked into the binary is valid there. Crates come from Cargo.lock (--locked).
# torch from PyPI is a CUDA build (about 4 GB with its nvidia-* libraries), which the GPU
# overlay uses and a CPU-only node simply does not.
ARG PYTHON_IMAGE=python:3.11.7-slim-bookworm
ARG RUST_IMAGE=rust:1.95.0-slim-bookworm

FROM ${RUST_IMAGE} AS rust

# ---------------------------------------------------------------- build
FROM ${PYTHON_IMAGE} AS build
RUN apt-get update \
 && apt-get install -y --no-install-recommends build-essential \
 && rm -rf /var/lib/apt/lists/*
COPY --from=rust /usr/local/cargo /usr/local/cargo
COPY --from=rust /usr/local/rustup /usr/local/rustup
ENV RUSTUP_HOME=/usr/local/rustup CARGO_HOME=/usr/local/cargo PATH=/usr/local/cargo/bin:$PATH \
    PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1

WORKDIR /opt/mo-mpo
COPY requirements.lock ./
# torch and its dependency closure, each at its requirements.lock version.
RUN python -m venv .venv \
 && .venv/bin/python -m pip install pip==25.3 \
 && .venv/bin/python -m pip install -c requirements.lock torch \
 && .venv/bin/python -m pip check

COPY . .
# .cargo/config.toml sets LIBTORCH_USE_PYTORCH=1 and puts /opt/mo-mpo/.venv/bin first on
# PATH for build scripts: torch-sys and agent/build.rs ask that venv's torch for libtorch.
RUN --mount=type=cache,target=/usr/local/cargo/registry \
    cargo build --release --locked -p agent \
 && install -D -m 0755 target/release/agent /opt/mo-mpo/bin/agent \
 && readelf -d /opt/mo-mpo/bin/agent | grep -F /opt/mo-mpo/.venv/lib/python3.11/site-packages/torch/lib

# ---------------------------------------------------------------- runtime
FROM ${PYTHON_IMAGE}
RUN useradd --uid 10001 --user-group --no-create-home --shell /usr/sbin/nologin agent \
 && install -d -o 10001 -g 10001 /runs
COPY --from=build /opt/mo-mpo/.venv /opt/mo-mpo/.venv
COPY --from=build /opt/mo-mpo/bin/agent /usr/local/bin/agent
# The NVIDIA container runtime mounts the driver when a GPU is assigned.
ENV NVIDIA_DRIVER_CAPABILITIES=compute,utility
# Fails the build if libtorch does not load from the rpath.
RUN agent --version
USER 10001:10001
WORKDIR /runs
ENTRYPOINT ["agent"]
CMD ["--help"]
