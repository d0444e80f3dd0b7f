"""Soak test of one `ciflow serve`: hostile payloads, crashing clients and honest steppers
at once, for minutes, with only `eclipse-zenoh` and `msgpack` (as a client written from
bridge/PROTOCOL.md would).

    .venv/bin/python bench/soak.py [--minutes 10] [--binary target/release/ciflow]

Every 10 s it prints the engine's resident memory, the hostile requests sent, the honest
steps taken, and the failures: panics (`internal` replies, or the engine dying), stalls (a
request unanswered, or a step slower than 1 s), and lost steps (a step whose simulated time
is not the previous one plus one control period). It exits non-zero if any failure was
seen. Not part of CI: it runs for minutes and takes every core.
"""

import argparse
import os
import random
import secrets
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import zenoh

V = 2
ROOT = Path(__file__).resolve().parent.parent
TASK = "limit-cycle"
STALL_SECONDS = 1.0


def open_session(endpoint: str) -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", f'["{endpoint}"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


def engine_prefix(engine: str, op: str) -> str:
    """Where `op` lives: what a client owns is under its identity (`soak`)."""
    owned = op in ("make", "limits") or op.startswith("session/")
    return f"ciflow/v2/engine/{engine}" + ("/client/soak" if owned else "")


class Plain:
    """A client from the protocol page: one Zenoh session, one liveliness token."""

    def __init__(self, endpoint: str, engine: str):
        self.session = open_session(endpoint)
        self.engine = engine
        self.instance = secrets.token_hex(6)
        self.token = self.session.liveliness().declare_token(f"ciflow/v2/alive/client/soak/{self.instance}")

    def raw(self, key: str, payload: bytes, timeout: float = 10.0):
        """Replies to one request: a list of (ok, payload bytes)."""
        replies = self.session.get(
            key, payload=payload, consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout
        )
        return [
            (True, r.ok.payload.to_bytes()) if r.ok is not None else (False, r.err.payload.to_bytes())
            for r in replies
        ]

    def query(self, key: str, request: dict):
        replies = self.raw(f"{engine_prefix(self.engine, key)}/{key}", msgpack.packb(request, use_bin_type=True))
        if len(replies) != 1:
            raise RuntimeError(f"{len(replies)} replies on {key}")
        ok, payload = replies[0]
        return ok, msgpack.unpackb(payload, raw=False)

    def make(self, num_envs: int = 1) -> dict:
        ok, reply = self.query("make", {"v": V, "instance": self.instance, "task": TASK, "num_envs": num_envs})
        if not ok:
            raise RuntimeError(f"make refused: {reply}")
        return reply


class Tally:
    def __init__(self):
        self.lock = threading.Lock()
        self.counts = {"hostile": 0, "steps": 0, "panics": 0, "stalls": 0, "lost": 0, "crashed clients": 0}
        self.failures: list[str] = []

    def add(self, key: str, n: int = 1, failure: str | None = None):
        with self.lock:
            self.counts[key] += n
            if failure is not None and len(self.failures) < 20:
                self.failures.append(failure)


def stepper(endpoint: str, engine: str, tally: Tally, stop: threading.Event):
    """An honest client: steps one session and checks that simulated time advances by
    exactly one control period per step, however hard the engine is pushed."""
    client = Plain(endpoint, engine)
    made = client.make()
    session, token, dt = made["session"], made["token"], made["spec"]["control_dt"]
    action = np.zeros(len(made["spec"]["action_space"]["low"]), dtype="<f8").tobytes()
    while not stop.is_set():
        client.query(f"session/{session}/reset", {"v": V, "token": token})
        expected = 0.0
        while not stop.is_set():
            started = time.monotonic()
            ok, reply = client.query(f"session/{session}/step", {"v": V, "token": token, "action": action})
            if time.monotonic() - started > STALL_SECONDS:
                tally.add("stalls", failure=f"step took {time.monotonic() - started:.2f} s")
            if not ok:
                tally.add("panics" if reply["code"] == "internal" else "lost", failure=f"step refused: {reply}")
                break
            expected += dt
            if abs(reply["time"] - expected) > 1e-9:
                tally.add("lost", failure=f"time {reply['time']} after a step, expected {expected}")
                expected = reply["time"]
            tally.add("steps")
            if reply["terminated"] or reply["truncated"]:
                break


def hostile_payload(rng: random.Random, token: bytes) -> bytes:
    """Garbage of every kind the page does not allow, and some it does."""
    kind = rng.randrange(8)
    if kind == 0:
        return rng.randbytes(rng.randrange(0, 256))
    if kind == 1:  # deep nesting
        depth = rng.randrange(1, 200_000)
        return b"\x91" * depth + b"\x01"
    if kind == 2:  # a length prefix far beyond the payload
        return b"\xdb\xff\xff\xff\xf0abc"
    if kind == 3:  # a big string
        return msgpack.packb({"v": V, "instance": "x" * rng.randrange(1, 1_000_000)})
    fields = ["v", "token", "action", "actions", "seed", "options", "context", "index", "instance", "task",
              "num_envs", "kwargs", "observations", "policy", "speed", "steps", "width", "height",
              "perturbation", "deadline_ms"]
    values = [None, True, -1, 0, 1, 2**32, 2**63, float("nan"), float("inf"), -1e308, "", "*", "a/b",
              b"", token, np.full(rng.randrange(0, 9), np.nan).tobytes(), [1, 2, 3], {"kind": "joint_torque"}]
    request = {"v": V if rng.random() < 0.8 else rng.choice(values)}
    for _ in range(rng.randrange(0, 6)):
        request[rng.choice(fields)] = rng.choice(values)
    return msgpack.packb(request, use_bin_type=True)


def attacker(endpoint: str, engine: str, tally: Tally, stop: threading.Event, seed: int):
    """Sends hostile requests to every operation, including sessions it owns."""
    rng = random.Random(seed)
    client = Plain(endpoint, engine)
    made = client.make(4)
    own = made["session"]
    ops = ["tasks", "make", "ping", "limits", "policy/none/act", "nothing/here"] + [
        f"session/{session}/{op}"
        for session in (own, "0000000000000000", "*")
        for op in ("reset", "step", "reset_batch", "step_batch", "expert", "context", "check_context",
                   "perturb", "render", "run", "stop")
    ]
    while not stop.is_set():
        op = rng.choice(ops)
        key = f"{engine_prefix(engine, op)}/{op}"
        payload = hostile_payload(rng, made["token"])
        started = time.monotonic()
        try:
            replies = client.raw(key, payload)
        except Exception as error:  # noqa: BLE001 - a refused key expression is the client's
            tally.add("hostile", failure=None if "*" in key else f"{key}: {error}")
            continue
        if not replies and "*" not in key:
            tally.add("stalls", failure=f"no reply on {key}")
        for ok, reply in replies:
            if not ok and msgpack.unpackb(reply, raw=False).get("code") == "internal":
                tally.add("panics", failure=f"internal on {key}")
        if time.monotonic() - started > 5:
            tally.add("stalls", failure=f"{key} took {time.monotonic() - started:.1f} s")
        tally.add("hostile")


def crasher(endpoint: str, engine: str, tally: Tally, stop: threading.Event):
    """Starts clients that make sessions and are killed without closing them."""
    while not stop.is_set():
        child = subprocess.Popen(
            [sys.executable, __file__, "--crash-child", endpoint, engine], stdout=subprocess.PIPE
        )
        child.stdout.readline()
        time.sleep(random.uniform(0.1, 1.0))
        child.send_signal(signal.SIGKILL)
        child.wait()
        tally.add("crashed clients")


def resident_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--binary", default=str(ROOT / "target/release/ciflow"))
    parser.add_argument("--port", type=int, default=27497)
    parser.add_argument("--attackers", type=int, default=4)
    parser.add_argument("--steppers", type=int, default=4)
    parser.add_argument("--crash-child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.crash_child:
        client = Plain(*args.crash_child)
        for _ in range(3):
            client.make(8)
        print("made", flush=True)
        time.sleep(3600)
        return

    endpoint, engine = f"tcp/127.0.0.1:{args.port}", "soak"
    server = subprocess.Popen(
        [args.binary, "serve", "--listen", endpoint, "--name", engine], stdout=subprocess.PIPE, text=True
    )
    try:
        if "ready" not in server.stdout.readline():
            sys.exit("the engine did not start")
        tally, stop = Tally(), threading.Event()
        workers = [threading.Thread(target=stepper, args=(endpoint, engine, tally, stop)) for _ in range(args.steppers)]
        workers += [threading.Thread(target=attacker, args=(endpoint, engine, tally, stop, seed))
                    for seed in range(args.attackers)]
        workers.append(threading.Thread(target=crasher, args=(endpoint, engine, tally, stop)))
        for worker in workers:
            worker.daemon = True
            worker.start()
        started = time.monotonic()
        print(f"{'s':>6} {'RSS MB':>8} " + " ".join(f"{k:>15}" for k in tally.counts))
        while time.monotonic() - started < args.minutes * 60:
            time.sleep(10)
            if server.poll() is not None:
                tally.add("panics", failure=f"the engine exited with {server.returncode}")
                break
            with tally.lock:
                counts = dict(tally.counts)
            print(f"{time.monotonic() - started:6.0f} {resident_mb(server.pid):8.1f} "
                  + " ".join(f"{v:>15}" for v in counts.values()), flush=True)
        stop.set()
        for worker in workers:
            worker.join(timeout=15)
        failed = tally.counts["panics"] + tally.counts["stalls"] + tally.counts["lost"]
        for failure in tally.failures:
            print("failure:", failure)
        print("soak passed" if failed == 0 else f"soak FAILED: {failed} failures")
        sys.exit(1 if failed else 0)
    finally:
        server.kill()
        server.wait()


if __name__ == "__main__":
    main()
