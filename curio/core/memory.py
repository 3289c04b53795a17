"""The C allocator's settings for a process that runs for days (glibc; elsewhere nothing).

glibc serves a large block (at least ``M_MMAP_THRESHOLD`` bytes, 128 KiB at start) with an
``mmap`` of its own and gives it back to the system with ``munmap`` as soon as it is freed.
But by default the threshold moves: once such a block is freed, glibc raises the threshold to
that block's size (up to 32 MiB), and from then on large temporary arrays of that size come
from the heap instead — and the heap keeps the memory they leave, resident, wherever anything
small was allocated after them. A rover allocates large temporaries now and then: the global
localisation search after a kidnap (its candidate poses and scores, megabytes), the
recorder's 4 MB chunks and their compression. Each kidnap of the 24-hour soak left the rover
2.8–4.6 MB bigger for good (docs/reliability.md, "Memory: the kidnaps").

:func:`tune_allocator` fixes both thresholds (setting them also stops glibc's adjustment):

* ``M_MMAP_THRESHOLD`` at :data:`MMAP_THRESHOLD_BYTES` (1 MiB): every block this large goes
  back to the system when it is freed;
* ``M_TRIM_THRESHOLD`` at :data:`TRIM_THRESHOLD_BYTES` (16 MiB): the heap keeps up to this much
  free space at its top instead of giving it back and faulting it in again at the next cycle
  (with glibc's default of 128 KiB the guided tour cost 4 % more CPU, all of it page faults).

Measured (``curio bench``-style A/B of ``curio sim guided-tour``, 5 pairs): CPU ×1.000; six
global searches in one process: 184.1 → 184.4 MB, against 184.1 → 190.1 MB by default. A
``MALLOC_MMAP_THRESHOLD_`` or ``MALLOC_TRIM_THRESHOLD_`` in the environment (glibc's own
knobs) is left to win.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os

__all__ = ["MMAP_THRESHOLD_BYTES", "TRIM_THRESHOLD_BYTES", "tune_allocator"]

log = logging.getLogger("curio.core.memory")

M_TRIM_THRESHOLD = -1  # mallopt's parameter numbers (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 1024 * 1024
TRIM_THRESHOLD_BYTES = 16 * 1024 * 1024
_ENVIRONMENT = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")


def tune_allocator() -> bool:
    """Fix glibc's mmap and trim thresholds for this process (calling it again changes
    nothing). Returns True when they are fixed, by this call or by the environment; False
    where the C library has no ``mallopt`` (musl, macOS)."""
    if any(name in os.environ for name in _ENVIRONMENT):
        return True
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    fixed = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    if not fixed:
        log.warning("could not fix the C allocator's thresholds (mallopt refused)")
    return fixed
