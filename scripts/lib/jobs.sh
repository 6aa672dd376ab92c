# Sourced by the bench scripts that run several runs at once. reap: drops the finished
# runs from the array `pids` (the runs' process ids, each started as a background job
# of the calling shell), setting failed=1 when one of them exited non-zero.
reap() {
  local live=() p
  for p in "${pids[@]}"; do
    if kill -0 "$p" 2>/dev/null; then live+=("$p"); else wait "$p" || failed=1; fi
  done
  pids=("${live[@]}")
}
