"""Remote host policies over ZeroMQ: serve a policy from another process.

The policy process (``drivee2e serve-policy FILE --port N``) needs numpy,
pyzmq and this package's JAX-free modules only (``hostapi``, ``remote``,
``errors``): a PyTorch environment without JAX or Flax can serve a model to
the simulator running elsewhere. The simulator side uses :class:`RemotePolicy`,
itself a :class:`~drivee2e_jax.hostapi.HostPolicy`: ``reset`` / ``act`` are
forwarded over the socket. Policy specs ``remote://HOST:PORT`` name one
(:func:`parse_remote_spec`).

Sockets: the server is a ROUTER, the client a DEALER. Not REQ/REP, because
REQ's strict send/recv lockstep wedges the client socket after a timed-out
request (it can neither send again nor tell a late reply from the next one),
and a REP server serves strictly one request at a time from whoever asked. A
DEALER client tags every request with an id, waits with a poll deadline, and
drops stale replies; the ROUTER server routes each reply to the client that
asked, so several simulators (e.g. the workers of a sweep) can share one
policy server, and one that dies mid-request does not block the others.

Wire protocol (version :data:`PROTOCOL_VERSION`), chosen to need nothing
beyond numpy + pyzmq (msgpack is not guaranteed in a torch environment, and
pickle would let anyone who reaches the port run code): one ZeroMQ multipart
message per request and per reply,

  frame 0:      a UTF-8 JSON header ``{"v": 1, "id": n, "op": ..., ...,
                "arrays": [{"path": [...], "dtype": "<f4", "shape": [...]}]}``
  frames 1..n:  one raw C-order buffer per entry of ``arrays``, in order
                (``path`` as in ``hostapi.flatten``, e.g.
                ``["privileged", "ego", "xy"]``; numeric and bool dtypes only).

Requests (``op``) and their replies (every reply has ``ok``; on failure
``ok: false`` and ``error``, one line; otherwise):

* ``hello`` ``{protocol, package}`` -> ``{protocol, package, policy: {name,
  action_type, waypoint_dt, num_waypoints, required_sensors}, source, pid}``;
  a different protocol version is an error on both sides, a different
  package version a warning on the client.
* ``reset`` ``{meta: [row dict, ...]}`` -> ``{session}``: calls
  ``policy.reset(meta)``; the policy state stays in the server, under
  ``session`` (at most :data:`MAX_SESSIONS` live sessions, oldest evicted).
* ``act`` ``{session, step}`` + the observation arrays -> ``{action_type}`` +
  the action arrays (float32, checked by ``hostapi.check_action`` on both sides).
* ``close`` ``{session?}`` -> ``{}``: forgets the session (``serve(once=True)``
  then returns).

No authentication and no encryption: bind to loopback (the default) or a
trusted network only.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import sys
import threading
import time
import traceback
import warnings
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import zmq

from drivee2e_jax import __version__
from drivee2e_jax.errors import DriveE2EError, one_line
from drivee2e_jax.hostapi import (
    ACTION_TYPES,
    Controls,
    HostPolicy,
    Observation,
    Waypoints,
    batch_size,
    check_act_result,
    check_action,
    describe,
    flatten,
    from_fields,
    unflatten,
    validate_host_policy,
)

#: Bumped on any incompatible change of the messages above.
PROTOCOL_VERSION = 1
SCHEME = "remote://"
#: Policy states a server keeps at once; the oldest session is evicted first.
MAX_SESSIONS = 64
#: Default seconds a client waits for any reply (the first act may load / warm up a model).
DEFAULT_TIMEOUT_S = 60.0
#: Seconds a client waits for a dropped connection to come back before it gives up.
RECONNECT_GRACE_S = 2.0
_WIRE_KINDS = "biuf"  # bool, int, uint, float

# --------------------------------------------------------------------------
# Addresses
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RemoteSpec:
    """A parsed ``remote://HOST:PORT[:key=value,...]`` policy spec."""

    address: str  # "tcp://HOST:PORT"
    kwargs: dict
    name: str = ""


def is_remote_spec(spec: Any) -> bool:
    """True for a ``remote://...`` policy spec."""
    return isinstance(spec, str) and spec.startswith(SCHEME)


def parse_remote_spec(spec: str) -> RemoteSpec:
    """``remote://HOST:PORT[:key=value,...]`` -> :class:`RemoteSpec`.

    Keys: ``timeout_s`` (seconds to wait for any reply, a number) and
    ``name`` (renames the policy in the results). DriveE2EError (one line)
    on anything else. Example: ``remote://127.0.0.1:5555:timeout_s=120``.
    """
    if not is_remote_spec(spec):
        raise DriveE2EError(f"{spec}: not a remote policy spec (expected {SCHEME}HOST:PORT, e.g. {SCHEME}127.0.0.1:5555)")
    parts = spec[len(SCHEME):].split(":", 2)
    if len(parts) < 2 or not parts[0]:
        raise DriveE2EError(f"{spec}: expected {SCHEME}HOST:PORT[:timeout_s=S,name=N], e.g. {SCHEME}127.0.0.1:5555")
    host, port_s = parts[0], parts[1]
    try:
        port = int(port_s)
    except ValueError:
        port = -1
    if not 1 <= port <= 65535:
        raise DriveE2EError(f"{spec}: port {port_s!r} is not a number in 1..65535")
    kwargs: dict = {}
    name = ""
    for item in filter(None, (parts[2] if len(parts) > 2 else "").split(",")):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or key not in ("timeout_s", "name"):
            raise DriveE2EError(f"{spec}: unknown option {item!r} (expected timeout_s=SECONDS or name=NAME)")
        if key == "name":
            name = value
            continue
        try:
            kwargs[key] = float(value)
        except ValueError:
            kwargs[key] = -1.0
        if not kwargs[key] > 0:
            raise DriveE2EError(f"{spec}: timeout_s={value!r}, expected a positive number of seconds")
    return RemoteSpec(address=f"tcp://{host}:{port}", kwargs=kwargs, name=name)


def _normalize_address(address: str) -> str:
    if is_remote_spec(address):
        return parse_remote_spec(address).address
    if address.startswith(("tcp://", "ipc://", "inproc://")):
        return address
    return f"tcp://{address}"


# --------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------


class _WireError(Exception):
    """A malformed message (reported to the peer / the user as one line)."""


def encode(header: dict, arrays: Sequence[tuple[Sequence[str], np.ndarray]] = ()) -> list:
    """A multipart message: the JSON header (with ``arrays`` added) + one raw
    buffer per array."""
    specs, bufs = [], []
    for path, arr in arrays:
        a = np.asarray(arr)
        if not a.flags.c_contiguous:  # (np.ascontiguousarray would turn a 0-d array into 1-d)
            a = a.copy(order="C")
        if a.dtype.kind not in _WIRE_KINDS:
            raise _WireError(f"{'.'.join(path)} has dtype {a.dtype}; only numeric and bool arrays are sent")
        specs.append({"path": list(path), "dtype": a.dtype.str, "shape": list(a.shape)})
        bufs.append(memoryview(a).cast("B") if a.size else b"")
    head = json.dumps({**header, "arrays": specs}, default=_json_default, allow_nan=True).encode()
    return [head, *bufs]


def _json_default(value: Any):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def decode(frames: Sequence) -> tuple[dict, list[tuple[tuple[str, ...], np.ndarray]]]:
    """Inverse of :func:`encode`: (header, [(path, array)]); arrays are
    writable copies. Raises _WireError on a malformed message."""
    if not frames:
        raise _WireError("empty message")
    try:
        header = json.loads(bytes(frames[0]))
    except (ValueError, UnicodeDecodeError) as e:
        raise _WireError(f"the header is not JSON ({e})") from e
    if not isinstance(header, dict):
        raise _WireError("the header is not a JSON object")
    specs = header.pop("arrays", [])
    if not isinstance(specs, list) or len(specs) != len(frames) - 1:
        raise _WireError(f"the header lists {len(specs) if isinstance(specs, list) else '?'} arrays, "
                         f"the message has {len(frames) - 1} buffers")
    arrays = []
    for spec, frame in zip(specs, frames[1:]):
        try:
            path = tuple(str(p) for p in spec["path"])
            dtype = np.dtype(spec["dtype"])
            shape = tuple(int(s) for s in spec["shape"])
        except (KeyError, TypeError, ValueError) as e:
            raise _WireError(f"bad array entry {spec!r}") from e
        if not path or dtype.kind not in _WIRE_KINDS or any(s < 0 for s in shape):
            raise _WireError(f"bad array entry {spec!r}")
        buf = frame.buffer if isinstance(frame, zmq.Frame) else frame
        n = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if len(memoryview(buf).cast("B")) != n:
            raise _WireError(f"{'.'.join(path)}: {len(memoryview(buf).cast('B'))} bytes, expected {n} for {dtype} {shape}")
        arrays.append((path, np.frombuffer(buf, dtype=dtype).reshape(shape).copy()))
    return header, arrays


# --------------------------------------------------------------------------
# Server
# --------------------------------------------------------------------------


def serve(policy: HostPolicy, port: int, host: str = "127.0.0.1", *, source: str | None = None,
          once: bool = False, ready: Callable[[str], None] | None = None,
          log: Callable[[str], None] | None = None, stop: threading.Event | None = None,
          max_sessions: int = MAX_SESSIONS) -> None:
    """Serve ``policy`` on ``tcp://host:port`` until interrupted.

    ``port=0`` picks a free port. ``ready(address)`` is called once bound
    (the CLI prints the address). ``source`` (the policy file) starts every
    error message. Errors inside the policy, and bad requests, are answered
    with a one-line error (the traceback goes to ``log``, default stderr) and
    the server keeps serving. Returns after the first ``close`` when
    ``once``, when ``stop`` is set, or raises KeyboardInterrupt on Ctrl-C;
    ``policy.close()`` is called on the way out.
    """
    source = source or str(getattr(policy, "name", "policy"))
    validate_host_policy(policy, source)
    info = describe(policy)
    log = log or (lambda line: print(line, file=sys.stderr, flush=True))
    nonce = os.urandom(4).hex()
    counter = itertools.count(1)
    sessions: OrderedDict[str, list] = OrderedDict()  # session -> [state, batch size]

    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.ROUTER)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        try:
            if port == 0:
                sock.bind(f"tcp://{host}:*")
            else:
                sock.bind(f"tcp://{host}:{int(port)}")
        except zmq.ZMQError as e:
            raise DriveE2EError(f"cannot listen on tcp://{host}:{port}: {e} (is the port in use? try another --port)") from e
        address = sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        if ready is not None:
            ready(address)

        def handle(header: dict, arrays: list) -> tuple[dict, list]:
            op = header.get("op")
            if op == "hello":
                if header.get("protocol") != PROTOCOL_VERSION:
                    raise _WireError(f"protocol mismatch: the client speaks drivee2e remote protocol "
                                     f"{header.get('protocol')} (drivee2e-jax {header.get('package')}), this server "
                                     f"speaks {PROTOCOL_VERSION} (drivee2e-jax {__version__}); install the same "
                                     f"drivee2e-jax version on both sides")
                log(f"client hello: drivee2e-jax {header.get('package')}, protocol {header.get('protocol')}")
                return {"protocol": PROTOCOL_VERSION, "package": __version__, "policy": info,
                        "source": source, "pid": os.getpid()}, []
            if op == "reset":
                meta = header.get("meta")
                if not isinstance(meta, list) or not meta or not all(isinstance(r, dict) for r in meta):
                    raise _WireError("reset needs meta: a non-empty list of row dicts")
                try:
                    state = policy.reset(meta)
                except (Exception, SystemExit) as e:
                    log(traceback.format_exc().rstrip())
                    raise DriveE2EError(f"{source}: policy {info['name']!r} {_raised(e, source)} in reset") from e
                session = f"{nonce}-{next(counter)}"
                sessions[session] = [state, len(meta)]
                while len(sessions) > max_sessions:
                    sessions.popitem(last=False)
                log(f"session {session}: reset, {len(meta)} scenario(s)")
                return {"session": session}, []
            if op == "act":
                session, step = header.get("session"), header.get("step")
                if session not in sessions:
                    raise _WireError(f"unknown session {session!r} (expired, or the server restarted; reset first)")
                state, batch = sessions[session]
                sessions.move_to_end(session)
                where = f"{source}, step {step}"
                try:
                    obs = unflatten(Observation, arrays)
                except DriveE2EError as e:
                    raise _WireError(f"bad observation: {e}") from e
                if batch_size(obs, batch) != batch:
                    raise _WireError(f"observation batch size {batch_size(obs)}, the session was reset with {batch}")
                try:
                    result = policy.act(obs, state)
                except (Exception, SystemExit) as e:
                    log(traceback.format_exc().rstrip())
                    raise DriveE2EError(f"{source}: policy {info['name']!r} {_raised(e, source)} in act "
                                        f"at step {step}") from e
                action, state = check_act_result(result, where)
                action = check_action(action, info["action_type"], batch, where, num_waypoints=info["num_waypoints"])
                sessions[session][0] = state
                return {"action_type": info["action_type"]}, flatten(action)
            if op == "close":
                sessions.pop(header.get("session"), None)
                return {}, []
            raise _WireError(f"unknown op {op!r} (expected hello, reset, act or close)")

        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        while stop is None or not stop.is_set():
            if not poller.poll(200):
                continue
            frames = sock.recv_multipart(copy=False)
            ident, body = frames[0], frames[1:]
            header: dict = {}
            try:
                header, arrays = decode(body)
                reply, out = handle(header, arrays)
                reply = {"ok": True, **reply}
            except (_WireError, DriveE2EError) as e:
                reply, out = {"ok": False, "error": one_line(e)}, []
            except Exception as e:  # noqa: BLE001 - a bug must not take the server down; report it
                log(traceback.format_exc().rstrip())
                reply, out = {"ok": False, "error": one_line(f"{source}: server error: {type(e).__name__}: {e}")}, []
            reply.update(v=PROTOCOL_VERSION, id=header.get("id"), op=header.get("op"))
            try:
                msg = encode(reply, out)
            except _WireError as e:
                msg = encode({"ok": False, "error": one_line(e), "v": PROTOCOL_VERSION, "id": header.get("id")})
            sock.send_multipart([ident, *msg], copy=False)
            if once and header.get("op") == "close":
                break
    finally:
        sock.close(linger=0)
        try:
            policy.close()
        except Exception:  # noqa: BLE001 - best effort on the way out
            log(traceback.format_exc().rstrip())


# --------------------------------------------------------------------------
# Client
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RemoteState:
    """The client-side policy state of a remote batch: the server's session
    (the real state lives in the server) and the next step number."""

    session: str
    step: int = 0


class RemotePolicy(HostPolicy):
    """A :class:`HostPolicy` served by ``drivee2e serve-policy`` at ``address``
    (``remote://HOST:PORT``, ``tcp://HOST:PORT`` or ``HOST:PORT``).

    Connects and shakes hands on construction: ``name``, ``action_type``,
    ``waypoint_dt``, ``num_waypoints`` and ``required_sensors`` are the
    served policy's (``name`` overrides the name). ``reset(meta)`` returns a
    :class:`RemoteState`; ``act(obs, state)`` sends the observation (a
    ``hostapi.Observation``, or anything ``hostapi.from_fields`` reads) and
    returns the checked float32 action. Every failure is a one-line
    DriveE2EError naming the address (and the step): no reply within
    ``timeout_s``, the connection lost mid-request (the server died), a
    protocol mismatch, or an error inside the served policy. Not thread-safe;
    ``close()`` (or ``with``) releases the socket.
    """

    def __init__(self, address: str, timeout_s: float = DEFAULT_TIMEOUT_S, *, name: str | None = None):
        if not timeout_s > 0:
            raise DriveE2EError(f"remote policy at {address}: timeout_s={timeout_s!r}, expected a positive number")
        self.address = _normalize_address(address)
        self.timeout_s = float(timeout_s)
        self._ids = itertools.count(1)
        self._sessions: set[str] = set()
        ctx = zmq.Context.instance()
        self._sock = ctx.socket(zmq.DEALER)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._monitor = self._sock.get_monitor_socket(zmq.EVENT_CONNECTED | zmq.EVENT_DISCONNECTED)
        self._connected = self._ever_connected = False
        try:
            self._sock.connect(self.address)
        except zmq.ZMQError as e:
            self.close()
            raise DriveE2EError(f"remote policy at {self.address}: cannot connect: {e}") from e
        try:
            info = self._hello()
        except BaseException:
            self.close()
            raise
        pol = info.get("policy") or {}
        self.server_info = info
        self.name = str(name or pol.get("name") or "remote")
        self.action_type = pol.get("action_type")
        self.waypoint_dt = float(pol.get("waypoint_dt", 0.5))
        self.num_waypoints = pol.get("num_waypoints")
        self.required_sensors = tuple(pol.get("required_sensors") or ())
        fields = pol.get("observation_fields")
        self.observation_fields = None if fields is None else tuple(fields)
        if self.action_type not in ACTION_TYPES:
            self.close()
            raise DriveE2EError(f"remote policy at {self.address}: the server reports action_type "
                                f"{self.action_type!r}, expected 'controls' or 'waypoints'")

    # -- the HostPolicy interface ------------------------------------------

    def reset(self, meta: list[dict]) -> RemoteState:
        rows = [dict(r) for r in meta]
        if not rows:
            raise DriveE2EError(f"remote policy at {self.address}: reset needs at least one meta row")
        header, _ = self._request({"op": "reset", "meta": rows}, (), "reset")
        self._sessions.add(header["session"])
        return RemoteState(session=str(header["session"]))

    def act(self, obs: Observation, state: RemoteState) -> tuple[Controls | Waypoints, RemoteState]:
        if not isinstance(state, RemoteState):
            raise DriveE2EError(f"remote policy at {self.address}: act needs the state returned by reset(), "
                                f"got {type(state).__name__}")
        if not isinstance(obs, Observation):
            obs = from_fields(obs, Observation)
        step = state.step
        header, arrays = self._request({"op": "act", "session": state.session, "step": step}, flatten(obs),
                                       f"act (step {step})")
        where = f"remote policy at {self.address}, step {step}"
        cls = Controls if self.action_type == "controls" else Waypoints
        try:
            action = unflatten(cls, arrays)
        except DriveE2EError as e:
            raise DriveE2EError(f"{where}: malformed action in the reply: {e}") from e
        action = check_action(action, self.action_type, obs.batch_size, where, num_waypoints=self.num_waypoints)
        return action, RemoteState(session=state.session, step=step + 1)

    def close(self) -> None:
        """Forget this client's sessions on the server (best effort, short
        wait) and close the socket. Idempotent."""
        sock = getattr(self, "_sock", None)
        if sock is None or sock.closed:
            return
        self._drain_monitor()
        for session in list(getattr(self, "_sessions", ())) if self._connected else ():
            try:
                self._request({"op": "close", "session": session}, (), "close", timeout_s=min(self.timeout_s, 1.0))
            except DriveE2EError:
                break
        self._sessions = set()
        try:
            self._sock.disable_monitor()
        except zmq.ZMQError:
            pass
        self._monitor.close(linger=0)
        sock.close(linger=0)

    def __enter__(self) -> RemotePolicy:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RemotePolicy({self.address!r}, name={getattr(self, 'name', '?')!r})"

    # -- plumbing ----------------------------------------------------------

    def _hello(self) -> dict:
        header, _ = self._request({"op": "hello", "protocol": PROTOCOL_VERSION, "package": __version__}, (), "hello")
        if header.get("protocol") != PROTOCOL_VERSION:
            raise DriveE2EError(f"remote policy at {self.address}: protocol mismatch: the server speaks drivee2e "
                                f"remote protocol {header.get('protocol')} (drivee2e-jax {header.get('package')}), "
                                f"this client speaks {PROTOCOL_VERSION} (drivee2e-jax {__version__}); install the "
                                f"same drivee2e-jax version on both sides")
        if header.get("package") != __version__:
            warnings.warn(f"remote policy at {self.address}: the server runs drivee2e-jax {header.get('package')}, "
                          f"this client {__version__} (same protocol {PROTOCOL_VERSION}; results may differ)",
                          stacklevel=3)
        return header

    def _drain_monitor(self) -> bool:
        """Process pending connection events; True when a disconnect was seen."""
        lost = False
        while self._monitor.poll(0):
            frames = self._monitor.recv_multipart()
            event = int.from_bytes(frames[0][:2], "little")
            if event == zmq.EVENT_CONNECTED:
                self._connected = self._ever_connected = True
            elif event == zmq.EVENT_DISCONNECTED:
                self._connected, lost = False, True
        return lost

    def _request(self, header: dict, arrays, what: str, *, timeout_s: float | None = None) -> tuple[dict, list]:
        timeout = self.timeout_s if timeout_s is None else timeout_s
        prefix = f"remote policy at {self.address}"
        if self._sock.closed:
            raise DriveE2EError(f"{prefix}: {what}: the client is closed")
        req_id = next(self._ids)
        try:
            msg = encode({"v": PROTOCOL_VERSION, "id": req_id, **header}, arrays)
        except _WireError as e:
            raise DriveE2EError(f"{prefix}: {what}: cannot send the observation: {e}") from e
        self._drain_monitor()
        deadline = time.monotonic() + timeout
        if self._ever_connected and not self._connected:  # the server went away since the last request
            grace = min(timeout, RECONNECT_GRACE_S)
            until = time.monotonic() + grace
            while not self._connected:
                left = until - time.monotonic()
                if left <= 0 or not self._monitor.poll(max(1, int(left * 1000))):
                    break
                self._drain_monitor()
            if not self._connected:
                raise DriveE2EError(f"{prefix}: {what}: the connection to the server was lost and did not come back "
                                    f"within {grace:g} s: the policy server died or was stopped")
        if not self._sock.poll(int(timeout * 1000), zmq.POLLOUT):
            raise DriveE2EError(f"{prefix}: {what}: could not send within {timeout:g} s (no server there? start one "
                                f"with `drivee2e serve-policy FILE --port N`)")
        self._sock.send_multipart(msg, copy=False)
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        poller.register(self._monitor, zmq.POLLIN)
        while True:
            left_ms = int((deadline - time.monotonic()) * 1000)
            if left_ms <= 0:
                state = "" if self._connected else "; not connected: no server there, or it died"
                raise DriveE2EError(f"{prefix}: no reply to {what} within {timeout:g} s{state} (is `drivee2e "
                                    f"serve-policy` running there? raise timeout_s for a slow policy)")
            events = dict(poller.poll(left_ms))
            if self._monitor in events and self._drain_monitor():
                raise DriveE2EError(f"{prefix}: the connection was lost while waiting for the reply to {what}: "
                                    f"the policy server died or was stopped")
            if self._sock not in events:
                continue
            frames = self._sock.recv_multipart(copy=False)
            try:
                reply, out = decode(frames)
            except _WireError as e:
                raise DriveE2EError(f"{prefix}: {what}: malformed reply ({e}); is that a drivee2e serve-policy "
                                    f"server?") from e
            if reply.get("id") != req_id:
                continue  # a late reply to an earlier, timed-out request
            if not reply.get("ok"):
                raise DriveE2EError(f"{prefix}: {reply.get('error') or 'the server reported an error'}")
            return reply, out


def _raised(exc: BaseException, source: Any) -> str:
    """``raised Type: message at file:line`` (``called sys.exit(N) at ...``)
    for the client's one line: the place is the last traceback frame in the
    policy file ``source``, else the last frame of all (the server holds the
    traceback; the client sees only this line)."""
    frames = traceback.extract_tb(exc.__traceback__)
    try:
        want = os.path.realpath(str(source))
        mine = [f for f in frames if os.path.realpath(f.filename) == want]
    except (OSError, ValueError, TypeError):
        mine = []
    frame = (mine or frames or [None])[-1]
    where = f" at {frame.filename}:{frame.lineno}" if frame is not None else ""
    if isinstance(exc, SystemExit):
        return f"called sys.exit({exc.code!r}){where}"
    text = one_line(exc, 200)
    return f"raised {type(exc).__name__}" + (f": {text}" if text else "") + where
