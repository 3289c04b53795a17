"""Curio: an autonomous tour-guide stack for the Curio rover in one asyncio process."""

__version__ = "0.1.0"
