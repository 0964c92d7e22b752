"""A Rerun recording stream whose per-scan rows are sent in columns (the base of
:class:`fusion.rerun_logger.RerunLogger`): its time, one batch of rows per entity, each entity's
style logged once before its first row, and the Hough images copied into blocks.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr
from numpy.typing import ArrayLike, NDArray

from fusion.rerun_columns import ColumnBatch, ImageBatch
from fusion.rerun_scans import ScanRows
from fusion.rerun_view import entity_styles

# Hough images buffered per send: a send costs ~0.4 ms whatever its size, a row a copy of its
# pixels into a new block (the sinks keep reading the block sent). 86 of Intel's 24 kB images a
# block: 25 a send cost 16 µs an image, 100 cost 6 µs; a block of 4 MiB or more is mapped on
# huge pages by NumPy, whose first touch tripled the copy's 3 µs.
IMAGE_BLOCK_BYTES = 2 << 20
UNIX_TIME_THRESHOLD = 1e8  # s; a clock past 1973 is a wall clock, not a simulation's


class ColumnStream:
    """One recording stream and what is waiting to be sent on it."""

    def __init__(self, stream: rr.RecordingStream) -> None:
        self.stream = stream
        self._time_kind: str | None = None
        self._styles = entity_styles()
        self._batches: dict[str, ColumnBatch] = {}
        self._styled: set[str] = set()
        self._accumulator_entities: dict[tuple[int, int], str] = {}
        self._images: dict[str, ImageBatch] = {}  # the Hough images, by entity

    def _set_time(self, t: float, scan: int | None = None) -> None:
        """Time of an immediate log call; events between scans belong to no scan."""
        self.stream.reset_time()
        if scan is not None:
            self.stream.set_time("scan", sequence=int(scan))
        self.stream.set_time("time", **{self._clock(t): float(t)})

    def _clock(self, t: float) -> str:
        """``duration`` for a simulated clock, ``timestamp`` for Unix time; fixed at first use."""
        if self._time_kind is None:
            self._time_kind = "timestamp" if t > UNIX_TIME_THRESHOLD else "duration"
        return self._time_kind

    def _time_column(self, t: NDArray[np.float64]) -> rr.TimeColumn:
        return rr.TimeColumn("time", **{self._clock(float(t[0])): t})

    def _batch(self, entity: str, archetype: Any, style: Any = None) -> ColumnBatch:
        batch = self._batches.get(entity)
        if batch is None:
            batch = self._batches[entity] = ColumnBatch(entity, archetype)
            self._style_once(entity, style if style is not None else self._styles.get(entity))
        return batch

    def _style_once(self, entity: str, style: Any) -> None:
        if style is not None and entity not in self._styled:
            self._styled.add(entity)
            self.stream.log(entity, style, static=True)

    def _send(self, entity: str, archetype: Any, rows: ScanRows, picked: Any,
              lengths: ArrayLike | None, **data: Any) -> None:
        """One entity's rows (``picked``, None: every row), ``lengths`` instances each (None:
        one), with one ``send_columns`` call; its style is logged before its first rows."""
        self._style_once(entity, self._styles.get(entity))
        t, scan = np.asarray(rows.t), np.asarray(rows.scan)
        if picked is not None:
            t, scan = t[picked], scan[picked]
        if len(t) == 0:
            return
        self.stream.send_columns(
            entity, indexes=[self._time_column(t), rr.TimeColumn("scan", sequence=scan)],
            columns=archetype.columns(**data).partition(
                np.ones(len(t), np.int64) if lengths is None else lengths))

    def _accumulator(self, t: float, index: int, votes: NDArray | None, n_points: int) -> None:
        """The vote image, copied into a block sent when ``IMAGE_BLOCK_BYTES`` are full (and with
        the other batches). Its format is static per entity: a grid of another shape (another
        sensor's settings) gets its own entity."""
        if votes is None:
            return
        h, w = votes.shape
        entity = self._accumulator_entities.get((h, w))
        if entity is None:
            entity = self._accumulator_entities[(h, w)] = (
                "hough/accumulator" if not self._accumulator_entities
                else f"hough/accumulator/{h}x{w}")
        batch = self._images.get(entity)
        if batch is None:  # the format and style once: building them costs more than the row
            # A cell gets at most one vote per point: 8 bits hold every vote of a sensor whose
            # first scan has at most 255 points (a 180-beam laser: half the bytes of 16 bits);
            # a later scan of more points is drawn saturated there. 16 bits otherwise.
            dtype = np.uint8 if n_points <= 255 else np.uint16
            rows = max(IMAGE_BLOCK_BYTES // (h * w * np.dtype(dtype).itemsize), 1)
            batch = self._images[entity] = ImageBatch(entity, (h, w), dtype, rows)
            self._style_once(entity, rr.DepthImage.from_fields(
                format=rr.components.ImageFormat(
                    width=w, height=h,
                    channel_datatype="U8" if dtype is np.uint8 else "U16"),
                meter=1.0, colormap="viridis", draw_order=0.0))
        if batch.add(t, index, votes, n_points):  # a cell gets at most a vote per point
            batch.send(self.stream, self._time_column)
