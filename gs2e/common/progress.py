"""Progress bars (tqdm on stderr; silent when stderr is not a terminal unless forced)."""

from __future__ import annotations

import os
import sys
from typing import Iterable, TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")


def progress(iterable: Iterable[T], desc: str, total: int | None = None, **kw) -> Iterable[T]:
    """Wrap ``iterable`` in a tqdm bar. In logs (non-tty) the bar updates at most
    every 10 s so log files stay readable; GS2E_PROGRESS=0 disables it."""
    disable = os.environ.get("GS2E_PROGRESS", "1") == "0"
    mininterval = 0.1 if sys.stderr.isatty() else 10.0
    return tqdm(iterable, desc=desc, total=total, disable=disable,
                mininterval=mininterval, file=sys.stderr, **kw)
