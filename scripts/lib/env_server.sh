# Sourced by the bench scripts. start_env_server LOG: a local env_server on an OS-chosen
# port, its output in LOG; sets server_pid, and address (host:port) once it listens
# (exits the script if it does not within 60 s). The caller's EXIT trap stops it with
# stop_env_server.
start_env_server() {
  .venv/bin/python -m env_server --host 127.0.0.1 --port 0 --log-level WARNING >"$1" 2>&1 &
  server_pid=$!
  for _ in $(seq 600); do grep -q LISTENING "$1" && break; sleep 0.1; done
  address=$(sed -n 's/^LISTENING //p' "$1")
  [[ -n $address ]] || { cat "$1"; echo "env_server did not start" >&2; exit 1; }
}

# stop_env_server: stops and reaps the server start_env_server started, if it started
# one. For EXIT traps, which run under the script's set -e: a bare `kill $server_pid`
# with no server fails, and its status 2 would replace the script's own.
stop_env_server() {
  if [[ -n ${server_pid:-} ]]; then
    kill "$server_pid" 2>/dev/null || true
    wait "$server_pid" 2>/dev/null || true
  fi
}
