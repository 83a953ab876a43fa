"""Keep freed memory in the process: fewer page faults for the large arrays of a long run.

A calibration over windows allocates and frees arrays of a few megabytes many times
(each window's bands, Jacobians, tables).  glibc's allocator gives blocks above its
``mmap`` threshold their own mapping and returns them to the system when freed, and
trims the top of its heap as soon as 128 KiB are free there: every such array then
costs fresh, zeroed pages, which the kernel fills on first touch.  On 1 M plots in
two-hour windows that was 1.9-2.5 s of system time; with freed blocks kept for reuse
(:func:`keep_freed_memory`) it is 0.9-1.2 s, and the run is 0.5-1 s shorter, for
2-3 % more peak memory.  Both settings are needed: a high trim threshold alone made
the run slower.

Only on Linux with glibc (elsewhere nothing is done).  The command line calls it once
at start; the processes it forks (the reader, the forked copy) inherit it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

#: glibc ``mallopt`` parameters (``malloc.h``).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: Blocks up to this size [bytes] come from the heap, not their own mapping.
MMAP_THRESHOLD_BYTES = 256 << 20
#: The heap's top is returned to the system only beyond this much free memory [bytes].
TRIM_THRESHOLD_BYTES = 512 << 20


def keep_freed_memory() -> bool:
    """Raise glibc's ``mmap`` and trim thresholds (module docstring); returns whether
    they were set (``False`` off Linux, or without glibc)."""
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


__all__ = ["M_MMAP_THRESHOLD", "M_TRIM_THRESHOLD", "MMAP_THRESHOLD_BYTES",
           "TRIM_THRESHOLD_BYTES", "keep_freed_memory"]
