"""The allocator setting (curio/core/memory.py): in the soak the rover's resident size swung by
8–11 MB from minute to minute and climbed in steps for the first 40 active minutes of every
process, while glibc moved its mmap threshold up to each large block it freed; with the end
state set at the start the 24-hour soak's seed 1 grew 3.0 MB/h instead of 12.3 (pooled over
its processes)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

PROBE = textwrap.dedent("""
    import ctypes, json, sys
    import numpy as np
    from curio.core.memory import tune_allocator

    class MallInfo2(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks",
                    "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]

    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = MallInfo2
    tuned = tune_allocator() if sys.argv[1] == "tuned" else None
    block = np.ones(8 * 1024 * 1024 // 8)  # an 8 MB array, as a large temporary
    mapped = libc.mallinfo2().hblkhd
    del block
    print(json.dumps({"tuned": tuned, "mapped_mb": mapped / 1e6}))
""")


def _run(mode: str) -> dict[str, object]:
    env_free = {k: v for k, v in __import__("os").environ.items()
                if not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True,
                         check=True, env=env_free, timeout=60)
    return json.loads(out.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def test_large_blocks_come_from_the_heap_from_the_start() -> None:
    """By default glibc maps an 8 MB block of its own (and unmaps it when freed, until its
    threshold moves up); tuned, the block comes from the heap at once, as it would after
    glibc's own adjustment."""
    default, tuned = _run("default"), _run("tuned")
    assert float(default["mapped_mb"]) >= 8.0  # type: ignore[arg-type]
    assert tuned["tuned"] is True and float(tuned["mapped_mb"]) < 1.0  # type: ignore[arg-type]


RSS_PRELUDE = textwrap.dedent("""
    import json, sys, threading
    import numpy as np
    from curio.core.memory import reserve_heap, tune_allocator

    def rss_mb():
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * 4096 / 1e6
""")

RESERVE = RSS_PRELUDE + textwrap.dedent("""
    if sys.argv[1] == "tuned":
        tune_allocator()
    before = rss_mb()
    taken = reserve_heap()
    reserved = rss_mb()
    for _ in range(3):  # large transient work met later: a global search, a help episode
        work = np.ones(2 * 1024 * 1024)  # 16 MB
        del work
    print(json.dumps({"taken": taken, "reserve_mb": reserved - before,
                      "later_mb": rss_mb() - reserved}))
""")

THREAD = RSS_PRELUDE + textwrap.dedent("""
    if sys.argv[1] == "tuned":
        tune_allocator()
        reserve_heap()
    before = rss_mb()
    kept = []

    def work():  # a writer thread's buffers: 12 MB of 64 KB blocks, a quarter kept
        blocks = [np.ones(8 * 1024) for _ in range(192)]
        kept.extend(blocks[::4])
        del blocks

    t = threading.Thread(target=work)
    t.start()
    t.join()
    print(json.dumps({"grew_mb": rss_mb() - before}))
""")


def _tuned_and_default(script: str) -> dict[str, dict[str, object]]:
    """``script``'s JSON line, run tuned and by glibc's defaults (no MALLOC_ knobs)."""
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("MALLOC_")}
    runs = {}
    for mode in ("tuned", "default"):
        out = subprocess.run([sys.executable, "-c", script, mode], capture_output=True,
                             text=True, check=True, env=env, timeout=60)
        runs[mode] = json.loads(out.stdout.strip().splitlines()[-1])
    return runs


def test_the_heap_reserve_holds_large_work_met_later() -> None:
    """The reserve is resident at once, and 16 MB of work afterwards fits in it (the
    resident size does not grow); untuned, no reserve is taken (glibc would trim it)."""
    runs = _tuned_and_default(RESERVE)
    tuned = runs["tuned"]
    assert tuned["taken"] is True and float(tuned["reserve_mb"]) >= 20.0, tuned  # type: ignore[arg-type]
    assert float(tuned["later_mb"]) < 1.0, tuned  # type: ignore[arg-type]
    assert runs["default"]["taken"] is False


def test_a_thread_allocates_from_the_main_heap_and_its_reserve() -> None:
    """A worker thread's allocations come from the main heap, where the reserve holds them
    (the resident size does not grow); by default glibc gives the thread an arena of its own,
    which grows by the thread's work and, with blocks still in use between the freed ones,
    keeps it."""
    runs = _tuned_and_default(THREAD)
    assert float(runs["tuned"]["grew_mb"]) < 1.0, runs  # type: ignore[arg-type]
    assert float(runs["default"]["grew_mb"]) > 5.0, runs  # type: ignore[arg-type]
