"""The one progress helper: tqdm bars on stderr (layer 0).

Library code takes a ``progress`` callback or flag; the bars themselves come
from here, so the CLI, the bench, sweeps and training look the same.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any

from tqdm import tqdm


def progress(iterable: Iterable | None = None, **kwargs: Any):
    """A tqdm progress bar on stderr, hidden when stderr is not a terminal."""
    kwargs.setdefault("disable", None)
    kwargs.setdefault("file", sys.stderr)
    kwargs.setdefault("dynamic_ncols", True)
    return tqdm(iterable, **kwargs)


class StepBar:
    """A tqdm bar over simulated steps, fed by ``update(done, total)`` callbacks
    (``evaluate(progress=bar.update)``); a no-op when disabled."""

    def __init__(self, name: str, enabled: bool):
        self.bar = None
        self.last = 0
        if enabled:
            self.bar = tqdm(total=None, desc=f"{name:>12}", unit="step", leave=True, dynamic_ncols=True)

    def update(self, done: int, total: int) -> None:
        if self.bar is None:
            return
        if self.bar.total != total:
            self.bar.total = total
        self.bar.update(done - self.last)
        self.last = done

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
