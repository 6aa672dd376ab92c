"""Give a closed session's memory back to the OS.

Sixty Make/Close cycles of humanoid-run with B = 20 left the server at 670-1200 MiB RSS
with no session open. Two things held it: the simulators (dm_control, MuJoCo) are
reference cycles that wait for Python's cyclic collector, and the memory they free
stays in glibc's malloc arenas. `release_memory` runs the collector and then
`malloc_trim(0)`, which returns the free pages of every arena. Other C libraries (musl,
macOS) have no malloc_trim; there only the collector runs.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import sys
from collections.abc import Callable


def _load_malloc_trim() -> Callable[[int], int] | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


_MALLOC_TRIM = _load_malloc_trim()


def release_memory() -> None:
    """Collect reference cycles, then return free heap pages to the OS (tens of ms)."""
    gc.collect()
    if _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)
