"""A run's rows kept on disk as they are recorded, and its arrays written from there block by
block: ``sim`` with flat memory (its memory does not grow with the duration).

- ``SpooledSeries`` takes a follower's rows as ``recording.FollowerSeries`` does (tick by tick,
  in order) and keeps ``block_rows`` of them in memory: each full block is appended to one file
  per ``FollowerSeries.GROUPS`` under the spool directory, raw float64 in C order; ``close``
  writes the rest (the rows never recorded: NaN, as ``FollowerSeries`` leaves them).
- ``Spooled`` reads them back a block at a time (``blocks``: the named series of each block,
  ``recording.series_arrays``).
- ``NpzBlocks`` writes an .npz from its arrays given a block at a time: each array's rows go to a
  file of their own as they come, and at ``close`` each member is copied into the archive after
  its header. Byte for byte what ``recording.save_npz`` writes of the whole arrays.

Memory: a block of each (``BLOCK_ROWS``); disk: the spool, then the arrays twice until the
archive is written (the spool directory is removed then).
"""

import io
import shutil
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import STATE_SIZE
from swarm_sitl.rundir.recording import COMMAND_WIDTH, FollowerSeries, npz_member, series_arrays
from swarm_sitl.rundir.whole_files import whole

BLOCK_ROWS = 4096  #: rows of a follower kept in memory (the paper's law: about 2.5 MB)
_COPY_BYTES = 1 << 20


class SpoolError(ValueError):
    """A row recorded out of order (before a block already written)."""


class SpooledSeries:
    """Rows 0..``n_rows - 1`` of one follower (``FollowerSeries``' recording calls), spooled to
    ``spool_dir`` a block at a time (module docstring)."""

    def __init__(
        self,
        spool_dir: Path,
        n_rows: int,
        record_fields: Mapping[str, int],
        n_in: int = 0,
        block_rows: int | None = None,
    ):
        """``block_rows``: default ``BLOCK_ROWS``."""
        spool_dir.mkdir(parents=True, exist_ok=True)
        self.dir, self.n = spool_dir, n_rows
        self.record_fields, self.n_in = dict(record_fields), n_in
        self.block_rows = max(1, min(block_rows or BLOCK_ROWS, n_rows))
        self._block = FollowerSeries(self.block_rows, record_fields, n_in)
        self.base = 0  #: the block's first row
        self._files: dict[str, IO[bytes]] | None = {
            g: open(spool_dir / f"{g}.f8", "wb")  # noqa: SIM115  (closed in close())
            for g in FollowerSeries.GROUPS
        }

    def _row(self, k: int) -> int:
        if k < self.base:
            raise SpoolError(f"row {k} recorded after rows from {self.base} on were written")
        while k >= self.base + self.block_rows:
            self._flush()
        return k - self.base

    def record_vehicle(self, k: int, t_s: float, state: np.ndarray, sample_t_s: float | None = None) -> None:
        self._block.record_vehicle(self._row(k), t_s, state, sample_t_s)

    def record_controller(
        self,
        k: int,
        command: AttitudeCommand,
        record: np.ndarray,
        in_age_s: np.ndarray | list[float] | None = None,
    ) -> None:
        self._block.record_controller(self._row(k), command, record, in_age_s)

    def _flush(self) -> None:
        assert self._files is not None, "closed"
        rows = min(self.block_rows, self.n - self.base)
        for g, f in self._files.items():
            a = getattr(self._block, g)
            a[:rows].tofile(f)
            a.fill(np.nan)
        self.base += self.block_rows

    def close(self) -> "Spooled":
        """Every row written (those never recorded NaN); what reads them back."""
        if self._files is not None:
            while self.base < self.n:
                self._flush()
            for f in self._files.values():
                f.close()
            self._files = None
        return Spooled(self.dir, self.n, self.record_fields, self.n_in)


class Spooled:
    """A follower's spooled rows (``SpooledSeries.close``), read back a block at a time."""

    def __init__(self, spool_dir: Path, n_rows: int, record_fields: Mapping[str, int], n_in: int):
        self.dir, self.n, self.record_fields = spool_dir, n_rows, dict(record_fields)
        #: each group's columns (None: one value a row)
        self.widths: dict[str, int | None] = {
            "t_s": None,
            "sample_t_s": None,
            "vehicle": STATE_SIZE,
            "command": COMMAND_WIDTH,
            "record": sum(self.record_fields.values()),
            "in_age_s": n_in,
        }

    def blocks(self, block_rows: int | None = None) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
        """``(first row, the block's named series)``, in order, ``block_rows`` rows each (default
        ``BLOCK_ROWS``)."""
        block_rows = block_rows or BLOCK_ROWS
        files = {g: open(self.dir / f"{g}.f8", "rb") for g in self.widths}  # noqa: SIM115
        try:
            for a in range(0, self.n, block_rows):
                rows = min(block_rows, self.n - a)
                groups = {}
                for g, width in self.widths.items():
                    data = np.fromfile(
                        files[g], dtype=np.float64, count=rows * (1 if width is None else width)
                    )
                    groups[g] = data if width is None else data.reshape(rows, width)
                yield a, series_arrays(groups, self.record_fields)
        finally:
            for f in files.values():
                f.close()


@dataclass
class SpooledRecording:
    """What a spooled run recorded (``sim``'s, ``running.sim``): each follower's rows on disk
    under ``spool_dir``, and what stays small in memory. Its leader's series are the trajectory
    at the ticks ``k * dt_s`` (``recording.leader_series``), computed when written."""

    spool_dir: Path
    followers: dict[int, Spooled]
    offsets: dict[int, np.ndarray]
    dt_s: float
    events: list[dict[str, Any]] = field(default_factory=list)


class NpzBlocks:
    """An .npz at ``path`` written from its arrays a block of rows at a time (module docstring):
    ``constants`` first (whole, e.g. a follower's offset), then each array in the order its
    first block named it. ``work_dir`` holds each array's rows until ``close``."""

    def __init__(self, path: Path, work_dir: Path, constants: Mapping[str, Any] | None = None):
        self.path, self.dir = path, work_dir
        work_dir.mkdir(parents=True, exist_ok=True)
        self._constants = {k: np.asanyarray(v) for k, v in (constants or {}).items()}
        self._files: dict[str, IO[bytes]] = {}
        self._shapes: dict[str, tuple[int, ...]] = {}
        self._dtypes: dict[str, np.dtype] = {}

    def add(self, arrays: Mapping[str, np.ndarray]) -> None:
        for name, a in arrays.items():
            if name not in self._files:
                self._files[name] = open(self.dir / f"{len(self._files)}.raw", "wb")  # noqa: SIM115
                self._shapes[name], self._dtypes[name] = (0, *a.shape[1:]), a.dtype
            np.ascontiguousarray(a).tofile(self._files[name])
            rows, *rest = self._shapes[name]
            self._shapes[name] = (rows + a.shape[0], *rest)

    def close(self) -> None:
        for f in self._files.values():
            f.close()
        with whole(self.path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
            for name, a in self._constants.items():
                self._member(z, name, a.shape, a.dtype, [np.ascontiguousarray(a).tobytes()])
            for name, f in self._files.items():
                self._member(z, name, self._shapes[name], self._dtypes[name], _chunks(Path(f.name)))
        shutil.rmtree(self.dir, ignore_errors=True)

    @staticmethod
    def _member(z: zipfile.ZipFile, name: str, shape: tuple[int, ...], dtype: np.dtype, chunks: Any) -> None:
        """As ``save_npz`` writes it: ``write_array``'s header (its 1.0 format, with the shape
        in Python ints), then the rows in C order, one entry of a known size."""
        header = _npy_header(tuple(int(x) for x in shape), dtype)
        info = npz_member(name)
        info.file_size = len(header) + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        with z.open(info, mode="w") as dest:
            dest.write(header)
            for chunk in chunks:
                dest.write(chunk)


def _npy_header(shape: tuple[int, ...], dtype: np.dtype) -> bytes:
    buf = io.BytesIO()
    d = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(buf, d)
    return buf.getvalue()


def _chunks(path: Path) -> Iterator[bytes]:
    with open(path, "rb") as f:
        while chunk := f.read(_COPY_BYTES):
            yield chunk
