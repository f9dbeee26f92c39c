"""`drivee2e serve-policy`: serve a host policy (any framework) to remote simulators over ZeroMQ.

Imports no JAX: the serving environment needs numpy, pyzmq and the policy's
own framework (PyTorch, ONNX Runtime, ...) only.
"""

from __future__ import annotations

from drivee2e_jax.cli.common import add_command

EPILOG = """\
examples:
  drivee2e serve-policy my_torch_policy.py --port 5555
  drivee2e serve-policy my_torch_policy.py:checkpoint=ckpt/best.pt,device=cuda --port 5555
  drivee2e serve-policy my_policy.py --port 5555 --host 0.0.0.0   # reachable from other machines
  drivee2e serve-policy my_policy.py --port 0 --once              # a free port; exit when the client closes

  # then, where the simulator runs:
  drivee2e bench --policy remote://127.0.0.1:5555

FILE defines `policy` or `make_policy(**kwargs)` returning a
drivee2e_jax.hostapi.HostPolicy (numpy in, numpy out, the whole batch per
step); FILE:key=value,... passes make_policy arguments (JSON values), and
name=... renames the policy. The server prints `serving NAME on ADDRESS` once
it listens, answers errors inside the policy with one-line messages (the
traceback goes to stderr) and keeps serving until Ctrl-C / SIGTERM.
The protocol has no authentication: keep the default --host 127.0.0.1 unless
the network is trusted.
"""


def add_parser(subparsers) -> None:
    p = add_command(subparsers, "serve-policy", help="serve a host policy (PyTorch, ONNX, ...) over ZeroMQ",
                    description="Load a host policy file and serve it over ZeroMQ, so that a simulator in another "
                    "process or environment can evaluate it with --policy remote://HOST:PORT. Imports no JAX.",
                    epilog=EPILOG)
    p.add_argument("policy", metavar="FILE", help="host policy file (.py), optionally FILE:key=value,...")
    p.add_argument("--port", type=int, required=True, help="TCP port to listen on (0: pick a free one)")
    p.add_argument("--host", default="127.0.0.1", help="interface to bind (default: 127.0.0.1, loopback only)")
    p.add_argument("--once", action="store_true", help="exit after the first client closes its session")
    p.set_defaults(func=run)


def run(args) -> int:
    import signal
    import sys
    import threading

    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.hostapi import load_host_policy
    from drivee2e_jax.policy import parse_policy_spec
    from drivee2e_jax.remote import serve

    if not 0 <= args.port <= 65535:
        raise DriveE2EError(f"--port {args.port}: expected a TCP port in 0..65535 (0: a free one)")
    path, kwargs, name = parse_policy_spec(args.policy)
    policy = load_host_policy(path, **kwargs)
    if name:
        policy.name = name
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    try:
        previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    except ValueError:  # not the main thread: Ctrl-C raises KeyboardInterrupt instead
        previous = {}

    def ready(address: str) -> None:
        print(f"serving {policy.name} ({policy.action_type}) from {path} on {address}", flush=True)

    try:
        serve(policy, args.port, args.host, source=str(path), once=args.once, ready=ready, stop=stop)
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    print("stopped", file=sys.stderr, flush=True)
    return 0
