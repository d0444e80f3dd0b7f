#!/usr/bin/env bash
# A stable policy beside an external 1 kHz controller, measured side by side in one run:
# the same fixed-rate loop asks `make demo`'s pouring policy shape (7 joints, 6-D context,
# 10 affine layers) for q̈_des (1) over Zenoh from Rust, next to a raw Zenoh query of the
# same size, (2) over Zenoh from Python (ciflow.Policy), (3) in process through the
# pure-Rust library. Each prints median, p99, max latency and missed 1 ms deadlines.
#
# Usage: bench/control_loop.sh [SECONDS per loop, default 60] [CHECKPOINT_DIR]
# Without a checkpoint, a pouring policy is trained here for one epoch on 8 expert
# demonstrations (its latency is that of any policy of the same shape).
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/workspace.sh
PORT=${PORT:-27491}
ENDPOINT=tcp/127.0.0.1:$PORT
SECONDS_PER_LOOP=${1:-60}
CIFLOW=$CARGO_TARGET_DIR/release/ciflow
scratch=$(mktemp -d)

cargo build --release --quiet --bin ciflow -p ciflow
cargo build --release --quiet -p ciflow-bridge --example control_loop --example control_loop_in_process
policy=${2:-}
if [ -z "$policy" ]; then
    policy=$scratch/pour
    "$CIFLOW" demos --task pouring --episodes 8 --out "$scratch/demos" > /dev/null
    "$CIFLOW" train --task pouring --demos "$scratch/demos" --out "$policy" --epochs 1 > /dev/null
fi
"$CIFLOW" serve --listen "$ENDPOINT" --name bench --policy "pour=$policy" > "$scratch/serve.log" &
server=$!
trap 'kill $server 2>/dev/null; wait $server 2>/dev/null || true; rm -rf "$scratch"' EXIT
for _ in $(seq 100); do grep -q ready "$scratch/serve.log" && break; sleep 0.1; done

echo "== one policy action per 1 ms period, $SECONDS_PER_LOOP s per loop ($(nproc) CPUs)"
"$CARGO_TARGET_DIR/release/examples/control_loop" "$ENDPOINT" bench pour --seconds "$SECONDS_PER_LOOP"
"$PYTHON" python_client/examples/control_loop.py "$ENDPOINT" pour --seconds "$SECONDS_PER_LOOP" \
    | grep -v "at 1 kHz"
"$CARGO_TARGET_DIR/release/examples/control_loop_in_process" "$policy" --seconds "$SECONDS_PER_LOOP" \
    | grep -v "at 1 kHz"
