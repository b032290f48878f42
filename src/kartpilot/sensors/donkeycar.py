"""Donkey Car tubs (format v2): ``manifest.json``, ``catalog_N.catalog`` JSON lines, ``images/``.

The manifest holds one JSON document per line: the input names, their types, metadata, the session,
and the catalogs' bookkeeping (``paths``, ``deleted_indexes``). Each catalog line is one record with
``_index``, ``_timestamp_ms``, the image's file name under ``cam/image_array`` and the driver's
``user/angle`` (-1 left to 1 right) and ``user/throttle``.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kartpilot.core.errors import DataError
from kartpilot.core.files import parse_json, read_text_file
from kartpilot.core.images import read_image
from kartpilot.core.types import FrameSet

__all__ = ["DonkeyTub", "TubRecord", "is_donkey_tub"]


@dataclass(frozen=True)
class TubRecord:
    index: int
    stamp_ms: int
    image_path: Path
    angle: float
    throttle: float


def is_donkey_tub(folder: str | Path) -> bool:
    folder = Path(folder)
    return (folder / "manifest.json").is_file() and any(folder.glob("catalog_*.catalog"))


class DonkeyTub:
    """The records of a tub, in index order, without the deleted ones."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        manifest = self.folder / "manifest.json"
        if not manifest.is_file():
            raise DataError(f"not a Donkey Car tub (no manifest.json): {self.folder}")
        try:
            documents = [parse_json(line, f"{manifest}, line {number}")
                         for number, line in enumerate(read_text_file(manifest).splitlines(), 1) if line.strip()]
        except DataError as exc:
            raise DataError(f"the tub's manifest is not JSON lines: {exc}") from None
        book = next((d for d in documents if isinstance(d, dict) and "paths" in d), None)
        if book is None:
            raise DataError(f"the tub's manifest {manifest} lists no catalogs")
        deleted = set(book.get("deleted_indexes", []))
        records = []
        for name in book["paths"]:
            path = self.folder / name
            if not path.is_file():
                raise DataError(f"the tub's catalog {path} is missing")
            for number, line in enumerate(read_text_file(path).splitlines(), 1):
                if not line.strip():
                    continue
                try:
                    row = parse_json(line, f"{path}, line {number}")
                    index = int(row["_index"])
                    if index in deleted:
                        continue
                    records.append(TubRecord(index, int(row["_timestamp_ms"]),
                                             self.folder / "images" / row["cam/image_array"],
                                             float(row.get("user/angle", 0.0)), float(row.get("user/throttle", 0.0))))
                except (DataError, KeyError, TypeError, ValueError) as exc:
                    raise DataError(f"{path} line {number} is not a tub record: {exc}") from exc
        if not records:
            raise DataError(f"the tub {self.folder} has no records")
        self.records = sorted(records, key=lambda r: r.index)
        for before, after in itertools.pairwise(self.records):
            if after.stamp_ms <= before.stamp_ms:  # the records' order is their index's; time must follow it
                raise DataError(f"the tub {self.folder}: record {after.index}'s time stamp ({after.stamp_ms} ms) "
                                f"{'repeats' if after.stamp_ms == before.stamp_ms else 'goes back from'} record "
                                f"{before.index}'s ({before.stamp_ms} ms)")

    def __len__(self) -> int:
        return len(self.records)

    @property
    def rate_hz(self) -> float:
        """The frame rate from the time stamps' median step (20 Hz, Donkey Car's default, if they say nothing)."""
        steps_ms = np.diff([r.stamp_ms for r in self.records])
        return 1000.0 / float(np.median(steps_ms)) if len(steps_ms) and np.median(steps_ms) > 0 else 20.0

    def frames(self) -> Iterator[FrameSet]:
        """The images as frame sets of one camera, ``center``; an unreadable image is skipped with an error."""
        for k, record in enumerate(self.records):
            image = read_image(record.image_path)
            yield FrameSet(k, record.stamp_ms * 1_000_000, {"center": image})
