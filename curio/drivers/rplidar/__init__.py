"""RPLidar A1: pure protocol, asyncio driver, byte-exact pty emulator and its part of
``curio check`` (``protocol``, ``driver``, ``emulator``, ``check``)."""
