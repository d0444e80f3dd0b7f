#!/usr/bin/env bash
# Step round trip vs raw Zenoh query round trip, from Rust and from Python, plus batched
# env-steps/s — all against one `ciflow serve` started here on a private port.
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/workspace.sh
PORT=${PORT:-27490}
ENDPOINT=tcp/127.0.0.1:$PORT

cargo build --release --quiet --bin ciflow -p ciflow
cargo build --release --quiet -p ciflow-bridge --example roundtrip
# Room for the largest batch of the example (the default limit is 65 536 per session).
"$CARGO_TARGET_DIR/release/ciflow" serve --listen "$ENDPOINT" --name bench \
    --max-envs-per-session 262144 --max-envs-per-client 524288 > /tmp/ciflow-bench-serve.log &
server=$!
trap 'kill $server 2>/dev/null; wait $server 2>/dev/null || true' EXIT
for _ in $(seq 100); do grep -q ready /tmp/ciflow-bench-serve.log && break; sleep 0.1; done

echo "== engine: ciflow serve on $ENDPOINT ($(nproc) CPUs)"
"$CARGO_TARGET_DIR/release/examples/roundtrip" "$ENDPOINT" bench
"$PYTHON" bench/roundtrip_python.py "$ENDPOINT"
