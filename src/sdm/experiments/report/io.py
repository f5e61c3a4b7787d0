"""Atomic writes for the report and the notebooks: the library's one writer, :mod:`sdm.io`, re-exported; and the
one reader of the CSVs it writes, :func:`read_csv`.

A file appears under its name only once it is complete, with the mode a plain
``open()`` gives it (``0o666 & ~umask``); see :mod:`sdm.io`.
"""
from __future__ import annotations

import io
from pathlib import Path

import pandas as pd

from ...errors import SDMInputError
from ...io import checksum_path, csv_damage, read_json, write_atomic, write_bytes, write_csv, write_json, write_text

__all__ = ["read_csv", "read_json", "write_atomic", "write_bytes", "write_csv", "write_json", "write_text"]


def read_csv(path: str | Path, **kwargs) -> pd.DataFrame:
    """The CSV at ``path`` as :func:`pandas.read_csv` reads it (``kwargs`` passed on), checked first against its
    checksum file (:func:`sdm.io.csv_damage`).

    Raises:
        SDMInputError: naming the file where it does not match its checksum file. A damaged result is then
            removed with its checksum file, so that the workflow's next run reruns the job that writes it.
    """
    path = Path(path)
    data = path.read_bytes()
    damage = csv_damage(path, data)
    if damage is not None:
        path.unlink(missing_ok=True)
        checksum_path(path).unlink(missing_ok=True)
        raise SDMInputError(f"{path}: damaged result: {damage}; removed, so the workflow's next run reruns the job "
                            "that writes it")
    return pd.read_csv(io.BytesIO(data), **kwargs)
