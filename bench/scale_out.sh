#!/usr/bin/env bash
# One vector environment over 1 and 2 engines behind a Zenoh router: env-steps/s and
# their ratio, measured in one run. Each engine is pinned to its own core and steps with
# one thread (RAYON_NUM_THREADS=1), so the ratio says how well a second engine adds up;
# beside it, the same environments stepped in one process on one and two threads (no
# Zenoh) say how well a second core adds up at all.
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/workspace.sh
PORT=${PORT:-27590}
ROUTER=tcp/127.0.0.1:$PORT

cargo build --release --quiet --bin ciflow -p ciflow
cargo build --release --quiet -p ciflow-bridge --example in_process_steps
CIFLOW="$CARGO_TARGET_DIR/release/ciflow"
pids=()
trap 'kill "${pids[@]}" 2>/dev/null; wait 2>/dev/null || true' EXIT
"$CIFLOW" router --listen "$ROUTER" > /tmp/ciflow-bench-router.log &
pids+=($!)
# Process ids by name, for the CPU each process spends per step (scale_out.py).
processes="router=$!"
for _ in $(seq 100); do grep -q ready /tmp/ciflow-bench-router.log && break; sleep 0.1; done
for k in 0 1; do
    RAYON_NUM_THREADS=1 taskset -c "$k" "$CIFLOW" serve --name "scale-$k" --connect "$ROUTER" \
        --listen "tcp/127.0.0.1:$((PORT + 1 + k))" > "/tmp/ciflow-bench-engine-$k.log" &
    pids+=($!)
    processes+=",scale-$k=$!"
    for _ in $(seq 100); do grep -q ready "/tmp/ciflow-bench-engine-$k.log" && break; sleep 0.1; done
done
"$PYTHON" bench/scale_out.py "$ROUTER" scale-0 scale-1 "$CARGO_TARGET_DIR/release/examples/in_process_steps" \
    "$processes"
