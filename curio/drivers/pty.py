"""The device end of an emulated USB serial line: a pseudo-terminal, and pacing its bytes.

:class:`PtyDevice` opens a pty pair, puts it in raw mode, and publishes the slave under a stable
symlink (like ``/dev/curio-lidar`` on the rover) so a driver can open ``device.path`` again and
again. ``unplug()`` closes the pty and removes the link, as pulling the USB cable removes the
device node (a driver holding it open gets ``EIO``); ``replug()`` makes a fresh pty behind the
same link. Writes never block: bytes that the kernel buffer cannot take are dropped and counted,
as a UART drops bytes nobody reads. The emulator reads the master side with ``loop.add_reader``;
the callback it gives is called with every chunk of bytes the driver wrote.

With ``watch_host`` (the Arduino, which resets when its port is opened) the device does not hold
the slave itself, so the master reports a hang-up while no client has the port open:
:meth:`PtyDevice.poll_host` notices a client opening it and starts reading, and a client closing
it (end of file on the master) stops reading until the next open; bytes written meanwhile are
discarded. Without it (the RPLidar) the device keeps the slave open and reads from :meth:`open` on.

:class:`BytePacer` keeps a fast simulated clock from racing ahead of pty delivery (emulated mode);
drivers and emulators both use it.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import fcntl
import os
import select
import shutil
import tempfile
import termios
import tty
from collections.abc import Callable
from pathlib import Path

from curio.core.clock import Clock

__all__ = ["BytePacer", "PtyDevice"]


class PtyDevice:
    """The device end of a serial line on a pseudo-terminal.

    Args:
        name: the link's file name (e.g. ``curio-lidar``).
        on_bytes: called on the event loop with each chunk the driver wrote.
        link_dir: where the symlink lives (a fresh temporary directory by default).
        watch_host: do not hold the slave open: see whether a client has the port open
            (:meth:`poll_host`) and talk only while one has.
    """

    def __init__(
        self,
        name: str,
        on_bytes: Callable[[bytes], None],
        link_dir: Path | None = None,
        *,
        watch_host: bool = False,
    ) -> None:
        self._own_dir = link_dir is None
        self._dir = Path(tempfile.mkdtemp(prefix="curio-emu-")) if link_dir is None else link_dir
        self.path = str(self._dir / name)
        self._on_bytes = on_bytes
        self.watch_host = watch_host
        self._master: int | None = None
        self._slave: int | None = None
        self._tty_name: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._reading = False
        self.host_open = False  # a client has the port open (always, while plugged, unwatched)
        self.bytes_written = 0
        self.bytes_dropped = 0
        self.bytes_read = 0

    @property
    def plugged(self) -> bool:
        """True while the pty exists."""
        return self._master is not None

    @property
    def tty_path(self) -> str | None:
        """The pty slave's own path (``/dev/pts/N``), or None when unplugged."""
        return self._tty_name

    def open(self) -> None:
        """Create the pty and the link (unwatched: on the event loop that will serve it)."""
        if self._master is not None:
            return
        master, slave = os.openpty()
        tty.setraw(slave, termios.TCSANOW)  # raw before anyone writes: no echo, no CR/LF
        tty.setraw(master, termios.TCSANOW)
        flags = fcntl.fcntl(master, fcntl.F_GETFL)
        fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self._tty_name = os.ttyname(slave)
        self._master, self._slave = master, slave
        if self.watch_host:
            os.close(slave)  # the master now reports hang-up until a client opens the slave
            self._slave = None
        tmp = self.path + ".tmp"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(self._tty_name, tmp)
        os.replace(tmp, self.path)
        if not self.watch_host:
            self._start_reading()

    def poll_host(self) -> bool:
        """With ``watch_host``: True once a client has opened the port since the last call
        (reading starts then); False while nobody has or it is already known to be open."""
        if self._master is None or self.host_open:
            return False
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        if any(ev & select.POLLHUP for _, ev in poller.poll(0)):
            return False
        self._start_reading()
        return True

    def _start_reading(self) -> None:
        assert self._master is not None
        self.host_open = True
        self._reading = True
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(self._master, self._readable)

    def stop_reading(self) -> None:
        """Stop reading and forget the client: with ``watch_host`` the next :meth:`poll_host`
        sees the port as newly opened (the emulator stopped serving, or the client closed it)."""
        if self._reading and self._master is not None and self._loop is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._master)
        self._reading = False
        self.host_open = False

    def _readable(self) -> None:
        if self._master is None:
            return
        try:
            data = os.read(self._master, 65536)
        except BlockingIOError:
            return
        except OSError:
            self.stop_reading()
            return
        if not data:
            self.stop_reading()
            return
        self.bytes_read += len(data)
        self._on_bytes(data)

    def write(self, data: bytes) -> int:
        """Send ``data`` to the driver; return the bytes accepted (0 when unplugged or, watched,
        while no client has the port open)."""
        if self._master is None or not self.host_open or not data:
            return 0
        try:
            n = os.write(self._master, data)
        except BlockingIOError:
            n = 0
        except OSError as exc:  # the client closed the port, or the pty went away under us
            if exc.errno not in (errno.EIO, errno.EBADF):
                raise
            self.stop_reading()
            n = 0
        self.bytes_written += n
        self.bytes_dropped += len(data) - n
        return n

    def unplug(self) -> None:
        """Close the pty and remove the link, as pulling the USB cable does."""
        if self._master is None:
            return
        self.stop_reading()
        with contextlib.suppress(FileNotFoundError):
            Path(self.path).unlink()
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        self._tty_name = None

    def replug(self) -> None:
        """A fresh pty behind the same link."""
        self.unplug()
        self.open()

    def close(self) -> None:
        """Unplug and remove the temporary directory."""
        self.unplug()
        if self._own_dir:
            shutil.rmtree(self._dir, ignore_errors=True)


class BytePacer:
    """Holds a simulated clock until the peer has read the bytes this side wrote to a pty.

    Emulated mode runs the real drivers and the emulators over pseudo-terminals on a
    ``SimClock`` that runs virtual time as fast as the CPU allows. The kernel hands pty bytes
    to the reader a little later (a work queue); meanwhile virtual time could move on, so when
    a message arrives would depend on the machine's load. :meth:`settle` keeps the calling task
    runnable — the ``SimClock`` does not advance while a task is ready — until
    ``peer_received()`` has caught up with ``sent()`` (exact byte counts on both sides), for at
    most ``max_spins`` loop turns. While ``active()`` is false (the peer has the port closed)
    unread bytes are written off at once. Without a peer (real hardware) it does nothing.

    Args:
        clock: the application clock (``sleep(0)`` yields one loop turn).
        sent: bytes this side has written so far.
        max_spins: loop turns to wait before writing the bytes off.
    """

    def __init__(self, clock: Clock, sent: Callable[[], int], max_spins: int = 5000) -> None:
        self.clock = clock
        self.sent = sent
        self.peer_received: Callable[[], int] | None = None
        self.active: Callable[[], bool] = lambda: True
        self.max_spins = max_spins
        self._offset = 0
        self.spins = 0
        self.write_offs = 0

    def _pending(self) -> int:
        assert self.peer_received is not None
        return self.sent() - self._offset - self.peer_received()

    async def settle(self) -> None:
        """Wait, without moving virtual time, until the peer has read what was sent."""
        if self.peer_received is None:
            return
        for _ in range(self.max_spins):
            pending = self._pending()
            if pending <= 0:
                self._offset += min(0, pending)
                return
            if not self.active():
                break
            self.spins += 1
            await self.clock.sleep(0.0)
        else:
            self.write_offs += 1
        self._offset += max(0, self._pending())
