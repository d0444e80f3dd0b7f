"""``python -m ciflow serve``: the embedded engine as a stand-alone process (the same
server as ``ciflow serve``, for machines with only the Python package)."""

import argparse
import sys
import time

from ciflow import _native, connection


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ciflow")
    commands = parser.add_subparsers(dest="command", required=True)
    serve = commands.add_parser("serve", help="host every task over Zenoh")
    serve.add_argument("--config", help="standard Zenoh JSON5 configuration file")
    serve.add_argument("--mode", choices=["peer", "client", "router"])
    serve.add_argument("--connect", action="append", help="endpoint to connect to")
    serve.add_argument("--listen", action="append", help="endpoint to listen on")
    serve.add_argument("--name", help="engine name used in key expressions")
    args = parser.parse_args(argv)

    # Before the engine starts its threads, so that they all inherit it.
    try:
        _native.run_as_batch()
    except OSError as error:
        print(f"python -m ciflow serve: running with the default scheduling policy ({error})",
              file=sys.stderr)
    engine = _native.Engine(
        config=args.config, mode=args.mode, connect=args.connect, listen=args.listen,
        name=args.name,
    )
    endpoints = ", ".join(args.listen or [connection.default_endpoint()])
    if engine.joined:
        endpoints += " (joined the engine there)"
    print(f"ciflow engine `{engine.name}` ready on [{endpoints}]", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        engine.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
