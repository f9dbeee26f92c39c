"""`tcp_traj`: the TCP-like baseline's trajectory head alone (the source's "TCP-traj" row).

Waypoints tracked by the simulator's PID + pure-pursuit controller; see
``drivee2e_jax/zoo/tcp.py`` (same checkpoint argument).
"""

from pathlib import Path

from drivee2e_jax.policy import load_policy


def make_policy(checkpoint=None, **config):
    return load_policy(Path(__file__).with_name("tcp.py"), checkpoint=checkpoint, mode="traj", **config)
