"""`tcp_ctrl`: the TCP-like baseline's control head alone (the source's "TCP-ctr" row).

Throttle / brake / steer straight from the network; see ``drivee2e_jax/zoo/tcp.py``
(same checkpoint argument).
"""

from pathlib import Path

from drivee2e_jax.policy import load_policy


def make_policy(checkpoint=None, **config):
    return load_policy(Path(__file__).with_name("tcp.py"), checkpoint=checkpoint, mode="ctrl", **config)
