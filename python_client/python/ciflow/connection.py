"""Finding an engine: an explicit one (``engine=`` / ``CIFLOW_ENGINE``), the one on the
default loopback endpoint, or — when none is reachable — one embedded in this process."""

from __future__ import annotations

import os
import threading

from ciflow import _native

_lock = threading.Lock()
_clients: dict[tuple, _native.ClientHandle] = {}
_embedded: _native.Engine | None = None
# The key of the embedded engine's client among those of `_client`.
_EMBEDDED = ("embedded", None, None)

_HOW_TO_START = (
    "Start an engine with `ciflow serve --listen tcp/0.0.0.0:7447` on that machine "
    "(or leave engine= unset to use one embedded in this process)."
)


# Zenoh's runtime (its threads and the sessions on them) does not survive `fork`: a
# process forked after this one opened a session would hang on its first request. Such a
# child refuses to open sessions instead (see `_refuse_in_forked_child`).
_opened_a_session = False
_forked_after_a_session = False
# The parent's clients, kept from being dropped in a forked child: closing their sessions
# there would wait on threads that exist only in the parent.
_inherited: list = []

_FORKED = (
    "ciflow cannot open a Zenoh session in a process forked after its parent opened one "
    "(Zenoh's threads do not survive fork; the request would hang). Start worker processes "
    "with 'spawn' or 'forkserver', e.g. gymnasium.make_vec(..., vectorization_mode='async', "
    "vector_kwargs={'context': 'spawn'}), or use ciflow's own vector environment (the "
    "default vectorization_mode), which steps every environment in this process."
)


def _after_fork_in_child() -> None:
    global _forked_after_a_session, _embedded
    if _opened_a_session:
        _forked_after_a_session = True
        _inherited.extend(_clients.values())
        _inherited.append(_embedded)
        _clients.clear()
        _embedded = None


os.register_at_fork(after_in_child=_after_fork_in_child)


def _refuse_in_forked_child() -> None:
    """Marks that this process opens a session, unless it is a child forked after its
    parent opened one (then raises)."""
    global _opened_a_session
    if _forked_after_a_session:
        raise RuntimeError(_FORKED)
    _opened_a_session = True


def _looks_like_endpoint(text: str) -> bool:
    return "/" in text and ":" in text


def default_endpoint() -> str:
    """Where the zero-configuration engine lives: ``CIFLOW_DEFAULT_ENDPOINT`` or
    ``tcp/127.0.0.1:7447`` (the variable lets tests use a private port)."""
    return os.environ.get("CIFLOW_DEFAULT_ENDPOINT") or _native.DEFAULT_ENDPOINT


def _client(connect: str | None, zenoh_config: str | None) -> _native.ClientHandle:
    # Who this process is behind a router with access control (see deploy/secure).
    identity = os.environ.get("CIFLOW_IDENTITY") or None
    # Keyed by the endpoint the default resolves to now: the variable may change.
    if connect is None and zenoh_config is None:
        connect = default_endpoint()
    key = (connect, zenoh_config, identity)
    client = _clients.get(key)
    if client is None:
        _refuse_in_forked_child()
        client = _native.ClientHandle.open(
            config=zenoh_config, connect=[connect] if connect else None, identity=identity
        )
        _clients[key] = client
    return client


def _embedded_client() -> _native.ClientHandle:
    """A client of the engine embedded in this process, starting it if needed."""
    global _embedded
    key = _EMBEDDED
    if key in _clients:
        return _clients[key]
    _refuse_in_forked_child()
    _embedded = _native.Engine(listen=[default_endpoint()])
    client = _native.ClientHandle.for_engine(_embedded)
    _clients[key] = client
    return client


def resolve(
    task: str | None, engine: str | None = None, zenoh_config: str | None = None
) -> tuple[_native.ClientHandle, str]:
    """Returns a client and the name of an engine that serves ``task``."""
    engine = engine or os.environ.get("CIFLOW_ENGINE") or None
    zenoh_config = zenoh_config or os.environ.get("CIFLOW_ZENOH_CONFIG") or None
    with _lock:
        if engine is None and zenoh_config is None:
            return _default(task)
        connect = engine if engine and _looks_like_endpoint(engine) else None
        try:
            client = _client(connect, zenoh_config)
        except _native.EngineUnreachable as error:
            # An engine's name is looked for through the default endpoint.
            where = connect or zenoh_config or default_endpoint()
            looking_for = f" (looking for engine {engine!r})" if engine and not connect else ""
            raise _native.EngineUnreachable(
                f"no ciflow engine reachable at {where}{looking_for}: {error}. {_HOW_TO_START}"
            ) from None
        if engine and not connect:
            client.engine_info(engine)  # raises EngineUnreachable if it does not answer
            return client, engine
        name = client.first_engine_serving(task)
        if name is None:
            raise _native.EngineUnreachable(
                f"no ciflow engine serving {task} answered via {engine or zenoh_config}. "
                + _HOW_TO_START
            )
        return client, name


def resolve_engines(
    task: str, engines: list[str] | str, engine: str | None = None,
    zenoh_config: str | None = None,
) -> tuple[_native.ClientHandle, list[str]]:
    """A client and the names of the engines to spread ``task`` over: ``engines`` as
    listed (each must answer and serve the task), or ``"*"`` for every engine serving it
    that the client reaches, in name order. ``engine`` (an endpoint) or ``zenoh_config``
    says how to reach them, e.g. through a Zenoh router."""
    zenoh_config = zenoh_config or os.environ.get("CIFLOW_ZENOH_CONFIG") or None
    engine = engine or os.environ.get("CIFLOW_ENGINE") or None
    if engine and not _looks_like_endpoint(engine):
        raise ValueError(f"with engines=, engine= is the endpoint to reach them by, not {engine!r}")
    try:
        with _lock:
            client = _client(engine, zenoh_config)
    except _native.EngineUnreachable as error:
        raise _native.EngineUnreachable(
            f"no ciflow engine reachable at {engine or zenoh_config or default_endpoint()}: "
            f"{error}. {_HOW_TO_START}") from None

    if engines != "*" and (isinstance(engines, str) or not engines):
        raise ValueError(f"engines= takes a list of engine names or '*', not {engines!r}")
    # The one lookup the command line's --engines uses too: duplicates, names and engines
    # that are missing (after a moment's grace) or do not serve the task are refused there.
    return client, client.resolve_engines(task, ["*"] if engines == "*" else list(engines))


def _default(task: str | None) -> tuple[_native.ClientHandle, str]:
    if _EMBEDDED in _clients:
        return _clients[_EMBEDDED], _embedded.name
    try:
        client = _client(None, None)
        name = client.first_engine_serving(task)
        if name is not None:
            return client, name
    except _native.EngineUnreachable:
        pass
    try:
        client = _embedded_client()
    except _native.EngineUnreachable:
        # Another process started an engine on the default endpoint just now.
        client = _client(None, None)
        name = client.first_engine_serving(task)
        if name is None:
            raise
        return client, name
    return client, _embedded.name


def client(engine: str | None, zenoh_config: str | None) -> _native.ClientHandle:
    """A client reaching ``engine`` (an endpoint) or the default endpoint, or through
    ``zenoh_config``; the client of this process's embedded engine when there is one and
    neither is given."""
    connect = engine if engine and _looks_like_endpoint(engine) else None
    with _lock:
        if connect is None and zenoh_config is None and _EMBEDDED in _clients:
            return _clients[_EMBEDDED]
        return _client(connect, zenoh_config)


def discover(engine: str | None = None, zenoh_config: str | None = None) -> list[dict]:
    """Lists reachable engines with their tasks (``[{"name", "tasks", "policies"}]``).

    With no argument, looks at the default endpoint and at the engine embedded in this
    process, if any. Never starts an engine.
    """
    engine = engine or os.environ.get("CIFLOW_ENGINE") or None
    zenoh_config = zenoh_config or os.environ.get("CIFLOW_ZENOH_CONFIG") or None
    connect = engine if engine and _looks_like_endpoint(engine) else None
    with _lock:
        found: dict[str, dict] = {}
        candidates = []
        if _EMBEDDED in _clients:
            candidates.append(_clients[_EMBEDDED])
        try:
            candidates.append(_client(connect, zenoh_config))
        except _native.EngineUnreachable:
            pass
        for client in candidates:
            for info in client.discover():
                found.setdefault(info["name"], info)
    return [found[name] for name in sorted(found) if not engine or connect or name == engine]


def shutdown_embedded_engine() -> None:
    """Stops the engine embedded in this process (its sessions close)."""
    global _embedded
    with _lock:
        _clients.pop(_EMBEDDED, None)
        if _embedded is not None:
            _embedded.close()
            _embedded = None
