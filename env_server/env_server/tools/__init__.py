"""Tools around the server, not part of it: each runs as `python -m env_server.tools.<name>`.

`ray` runs servers as Ray actors; `devcerts` makes throwaway TLS certificates and tokens;
`healthcheck` is the Kubernetes probes' command; `bench_inprocess` measures a Task's steps
in this process (no gRPC); `make_clips` records the synthetic mocap clips humanoid-mocap
ships. The server never imports this package.
"""
