"""The C allocator's settings for a process that runs for days (glibc; elsewhere nothing).

glibc serves a block of at least ``M_MMAP_THRESHOLD`` bytes (128 KiB at start) with an
``mmap`` of its own and unmaps it when it is freed. By default that threshold moves: each time
such a block is freed glibc raises it to the block's size (up to 32 MiB on 64-bit) and its
heap-trim threshold to twice that, so that from then on blocks of that size come from the heap
and stay resident. A rover that runs for days gets there anyway — after the first recorder
chunk, the first compression, the first global search, at times nobody chooses: in the soak the
resident size swung by 8–11 MB from minute to minute and climbed in steps for the first
40 minutes of every process (docs/reliability.md, "Memory: what the rover keeps, found").

:func:`tune_allocator` puts glibc in that end state at the start: ``M_MMAP_THRESHOLD`` at
:data:`MMAP_THRESHOLD_BYTES` (32 MiB, glibc's own ceiling) and ``M_TRIM_THRESHOLD`` at
:data:`TRIM_THRESHOLD_BYTES` (64 MiB, the ratio glibc keeps). Setting them also stops the
adjustment. A ``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_`` or ``MALLOC_ARENA_MAX``
in the environment (glibc's own knobs) is left to win.

:func:`reserve_heap`, called once the rover is built and its parts are started, then takes
:data:`RESERVE_BYTES` (24 MiB) from the heap, touches it and gives it back: the heap keeps it
(below the trim threshold), resident, and the large transient work a process meets for the
first time later — its first global search, its first help episode — fits in memory it already
has, instead of growing it then. This is the real-time practice of ROS 2 and others (prefault
the heap, do not trim), here for flat memory more than for page faults.

It also sets ``M_ARENA_MAX`` to 1 (:data:`ARENAS`): every thread allocates from that one heap.
By default glibc gives each thread that allocates an arena of its own, which grows with the
thread's work and is trimmed in steps. In the soak of 2026-12-07 one such arena (a worker
thread's: the recorder's writer, which encodes every message, is the thread that allocates all
the time) grew by 1.0–2.6 MB over each process's life, the growth the memory check reads as a
leak (docs/reliability.md, "Memory: a thread's arena"). From the main heap the same work fits
in the reserve.

Cost: none measured (`farm-bench -n 4 --pin 0`, `curio sim guided-tour --seed 1` with and
without it, 2026-12-01: CPU ×0.997, median of the pairs 0.978–1.015; peak 271.7 against 271.3
MiB).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os

__all__ = ["ARENAS", "MMAP_THRESHOLD_BYTES", "RESERVE_BYTES", "TRIM_THRESHOLD_BYTES",
           "reserve_heap", "tune_allocator"]

log = logging.getLogger("curio.core.memory")

M_TRIM_THRESHOLD = -1  # mallopt's parameter numbers (malloc.h)
M_MMAP_THRESHOLD = -3
M_ARENA_MAX = -8
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024
RESERVE_BYTES = 24 * 1024 * 1024  # below MMAP_THRESHOLD_BYTES: served from the heap
ARENAS = 1  # every thread allocates from the main heap (and its reserve)
_ENVIRONMENT = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_ARENA_MAX")
_tuned: list[bool] = []  # tune_allocator fixed the thresholds in this process


def _libc() -> ctypes.CDLL:
    """The C library (raises OSError where there is none to load)."""
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")


def tune_allocator() -> bool:
    """Fix glibc's mmap and trim thresholds and its single arena for this process (calling
    it again changes nothing). Returns True when they are fixed, by this call or by the
    environment; False where the C library has no ``mallopt`` (musl, macOS)."""
    if any(name in os.environ for name in _ENVIRONMENT):
        return True
    try:
        mallopt = _libc().mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    fixed = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)) and bool(mallopt(M_ARENA_MAX, ARENAS))
    if fixed and not _tuned:
        _tuned.append(True)
    if not fixed:
        log.warning("could not fix the C allocator's thresholds (mallopt refused)")
    return fixed


def reserve_heap() -> bool:
    """Grow glibc's heap by :data:`RESERVE_BYTES`, resident and free (see the module
    docstring). Only after :func:`tune_allocator` fixed the thresholds (else glibc would map
    the block and unmap it, or trim it); returns whether the reserve was taken."""
    if not _tuned:
        return False
    libc = _libc()
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    block = libc.malloc(RESERVE_BYTES)
    if not block:
        return False
    ctypes.memset(block, 0, RESERVE_BYTES)  # resident now
    libc.free(block)
    return True
