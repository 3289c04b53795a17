"""RPLidar A1: pure protocol, asyncio driver and a byte-exact pty emulator."""
