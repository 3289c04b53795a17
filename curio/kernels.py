"""Curio's compiled kernels (numba ``@njit(cache=True)``): where their machine code is cached,
how warm that cache is, and loading it before the rover starts.

numba compiles a kernel at its first call for the argument types of that call — seconds per
kernel here, half a minute and more for all of them on a Raspberry Pi — and keeps the machine
code on disk (``cache=True``). By default the cache sits next to the sources
(``curio/**/__pycache__``), which a system install run by the ``curio`` service user cannot
write: every boot would compile again, while the rover is already driving.

* :func:`use_cache_dir` applies the config's ``numba_cache_dir`` (``NUMBA_CACHE_DIR``) to
  numba and to every kernel already imported; the :class:`~curio.app.App` calls it first.
* :func:`status` (``curio check``) tells, per kernel, how many compiled variants the cache
  holds for the current sources (none: cold; a ``git pull`` makes the cache stale too).
* :func:`preload` loads every cached variant now (milliseconds each), so the first scan after
  a start never waits.
* :func:`watch_compiles` then logs every kernel that still compiles (a call with argument
  types or array layouts the warmup never produced: seconds of a stalled loop on a Pi, and
  megabytes of LLVM memory kept).

``curio warmup`` (:mod:`curio.commands.warmup`) fills the cache by driving the simulator, and
``curio run`` loads it (or, cold, fills it) before the rover starts.

The kernels are found by reading ``curio/**/*.py`` for ``@njit(cache=True``: a new kernel
module needs no registration.
"""

from __future__ import annotations

import importlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from curio.core.config import Config
from curio.core.errors import SetupError

__all__ = [
    "KernelStatus", "cache_dir", "describe", "dispatchers", "preload", "status", "use_cache_dir",
    "watch_compiles",
]

log = logging.getLogger("curio.kernels")

PACKAGE_DIR = Path(__file__).resolve().parent
MARKER = "@njit(cache=True"


@dataclass(frozen=True)
class KernelStatus:
    """One kernel's cache: ``name`` (``module.function``) and the number of compiled variants
    cached for the current source and machine (0: cold)."""

    name: str
    cached: int


def kernel_modules() -> list[str]:
    """Dotted names of the modules under ``curio/`` that define cached kernels."""
    names = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        try:
            text = path.read_text(encoding="utf-8")
        except OSError:  # pragma: no cover - unreadable file in the install
            continue
        if MARKER in text and path != Path(__file__).resolve():
            rel = path.relative_to(PACKAGE_DIR.parent).with_suffix("")
            names.append(".".join(rel.parts))
    return names


def dispatchers() -> dict[str, Any]:
    """Every cached kernel, ``{"module.function": dispatcher}`` (imports the kernel modules);
    helpers declared ``inline="always"`` are left out: they compile inside their callers."""
    from numba.core.registry import CPUDispatcher  # type: ignore[import-untyped]

    out: dict[str, Any] = {}
    for name in kernel_modules():
        module = importlib.import_module(name)
        for attr, obj in vars(module).items():
            cache = getattr(obj, "_cache", None)
            if (isinstance(obj, CPUDispatcher) and type(cache).__name__ != "NullCache"
                    and obj.py_func.__module__ == name
                    and obj.targetoptions.get("inline") != "always"):
                out[f"{name}.{attr}"] = obj
    return out


def cache_dir(cfg: Config) -> Path | None:
    """The configured ``numba_cache_dir``, resolved (None: numba's default, next to the
    sources, or ``NUMBA_CACHE_DIR`` from the environment)."""
    return None if cfg.numba_cache_dir is None else cfg.resolve(cfg.numba_cache_dir)


def describe(directory: Path | None) -> str:
    """Where numba's cache is, for messages: ``directory`` (what :func:`use_cache_dir`
    returned), else ``NUMBA_CACHE_DIR`` from the environment, else next to the sources."""
    if directory is not None:
        return str(directory)
    env = os.environ.get("NUMBA_CACHE_DIR")
    return f"NUMBA_CACHE_DIR={env}" if env else "next to the sources"


def use_cache_dir(cfg: Config) -> Path | None:
    """Point numba's cache at ``numba_cache_dir`` (created if missing) for the kernels to be
    imported and for those already imported; return the directory (None: unchanged)."""
    directory = cache_dir(cfg)
    if directory is None or os.environ.get("NUMBA_CACHE_DIR") == str(directory):
        return directory
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SetupError(
            f"numba_cache_dir = {str(directory)!r} cannot be created ({exc.strerror}): create "
            "it writable by the user that runs curio, or set numba_cache_dir to such a "
            "directory") from None
    os.environ["NUMBA_CACHE_DIR"] = str(directory)
    from numba.core import config as numba_config  # type: ignore[import-untyped]

    numba_config.reload_config()  # type: ignore[no-untyped-call]
    for disp in dispatchers().values():
        disp.enable_caching()  # a new cache object: it picks the new location
    return directory


def _cached_signatures(disp: Any) -> list[Any]:
    """The argument types of the variants the cache holds for this source and machine."""
    cache = disp._cache
    index = cache._cache_file._load_index()  # {} when missing or stale
    magic = disp.targetctx.codegen().magic_tuple()
    current = cache._index_key(None, disp.targetctx.codegen())[2]
    return [key[0] for key in index if key[1] == magic and key[2] == current]


def status() -> list[KernelStatus]:
    """Every kernel's cache status (see :class:`KernelStatus`)."""
    out = []
    for name, disp in dispatchers().items():
        try:
            cached = len(_cached_signatures(disp))
        except Exception:  # pragma: no cover - numba's cache layout changed
            log.debug("cannot read the cache index of %s", name, exc_info=True)
            cached = 0
        out.append(KernelStatus(name, cached))
    return out


def preload() -> tuple[int, list[str]]:
    """Load every cached variant of every kernel now; return how many were loaded and the
    kernels with nothing cached (those compile at their first call)."""
    loaded = 0
    cold = []
    for name, disp in dispatchers().items():
        try:
            sigs = _cached_signatures(disp)
        except Exception:  # pragma: no cover - numba's cache layout changed
            sigs = []
        for sig in sigs:
            disp.compile(sig)  # found in the cache: loaded, not compiled
            loaded += 1
        if not sigs:
            cold.append(name)
    return loaded, cold


_watching: list[Any] = []


def watch_compiles() -> None:
    """From now on, log a warning naming the kernel and its argument types whenever a kernel
    compiles (numba's ``numba:compile`` event fires on a real compilation, not on a load from
    the cache). Idempotent."""
    if _watching:
        return
    from numba.core import event

    class _Watch(event.Listener):  # type: ignore[misc]
        def on_start(self, ev: Any) -> None:
            pass

        def on_end(self, ev: Any) -> None:
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            module = getattr(func, "__module__", "") or ""
            if module.split(".")[0] == "numba":
                return  # numba's own helpers, compiled as part of a kernel
            name = f"{module}.{getattr(func, '__qualname__', '?')}"
            log.warning("kernel %s compiled while the rover runs, for %s: a call the warmup "
                        "does not make (curio/commands/warmup.py)", name, ev.data.get("args"))

    listener = _Watch()
    event.register("numba:compile", listener)  # type: ignore[no-untyped-call]
    _watching.append(listener)
