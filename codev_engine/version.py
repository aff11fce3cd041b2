"""The engine version: part of every session artifact's key (a new engine recomputes)."""

__version__ = "0.1.0"
