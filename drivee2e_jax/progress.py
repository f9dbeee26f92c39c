"""The one progress helper: tqdm bars on stderr (layer 0).

Library code reports progress through a callback (``ProgressFn``:
``progress(stage, done, total, info)``, or ``evaluate``'s ``progress(done,
total)``) and never draws anything itself; the CLI passes ``ProgressBars``
(one tqdm bar per stage), so the bench, sweeps and training look the same.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterable
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

    def __init__(self, name: str, enabled: bool, unit: str = "step"):
        self.bar = None
        self.last = 0
        if enabled:
            self.bar = tqdm(total=None, desc=f"{name:>12}", unit=unit, leave=True, dynamic_ncols=True)

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


#: ``progress(stage, done, total, info)``: ``done`` of ``total`` units of the
#: named stage are finished; ``info`` holds short values to show (e.g. the loss).
ProgressFn = Callable[[str, int, int, dict], None]


class ProgressBars:
    """A ``ProgressFn`` drawing one tqdm bar per stage on stderr (a new stage
    closes the previous bar); ``close()`` when the work is done."""

    def __init__(self, unit: str = "step"):
        self.unit = unit
        self.stage: str | None = None
        self.bar = None

    def __call__(self, stage: str, done: int, total: int, info: dict | None = None) -> None:
        if stage != self.stage:
            self.close()
            self.stage = stage
            self.bar = progress(total=total, initial=done, desc=stage, unit=self.unit)
        if self.bar.total != total:
            self.bar.total = total
        self.bar.n = done
        if info:
            self.bar.set_postfix(info, refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar, self.stage = None, None


@contextlib.contextmanager
def progress_bars(enabled: bool = True, unit: str = "step"):
    """``with progress_bars(not args.no_progress) as progress: train(..., progress=progress)``:
    a ``ProgressBars`` (None when disabled), closed when the block ends."""
    bars = ProgressBars(unit) if enabled else None
    try:
        yield bars
    finally:
        if bars is not None:
            bars.close()
