"""Atomic writes for the report and the notebooks: the library's one writer, :mod:`sdm.io`, re-exported.

A file appears under its name only once it is complete, with the mode a plain
``open()`` gives it (``0o666 & ~umask``); see :mod:`sdm.io`.
"""
from __future__ import annotations

from ..io import read_json, write_atomic, write_bytes, write_csv, write_json, write_text

__all__ = ["read_json", "write_atomic", "write_bytes", "write_csv", "write_json", "write_text"]
