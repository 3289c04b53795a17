"""Command-line tools behind ``curio check``, ``curio emulate``, ``curio map`` and
``curio bench`` (``curio/cli.py`` dispatches to them)."""
