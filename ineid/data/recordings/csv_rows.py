"""A recording CSV's rows, read within stated limits into float64 arrays of the columns used.

A lab's CSV can be long (an hour at 4 kHz is 14.4 million rows) and anything can be named as
one (a FIFO, a file of 100,000 columns, a cell of ``1e308``). The file is checked before it is
opened (:func:`ineid._inputs.regular_file`, :data:`MAX_CSV_BYTES`), its header against
:data:`MAX_COLUMNS`, and its body is read in blocks of :data:`BLOCK_CHARS` characters, each cut
at its last line end (no line longer than :data:`MAX_LINE_CHARS`): memory holds one block of
text and the numbers of the columns read, never the file's text or its rows as Python lists.

Each block is parsed by NumPy (``loadtxt``, empty cells read as NaN) when it can be: no quotes,
no ``n``/``N`` (so every NaN is an empty cell), every row as wide as the header, every value
within its limit (:data:`ineid.data.recordings.streams.VALUE_LIMIT`, :data:`ineid.data.recordings.streams.TIME_LIMIT`),
each stream's cells all there or all empty. A block that does not pass is read row by row with
the same rules, which name the first bad cell (line, column, value): both ways give the same
arrays or the same error.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import numpy as np

from ineid._faults import require_memory
from ineid.data.recordings.streams import TIME_LIMIT, VALUE_LIMIT
from ineid.errors import DatasetError

MAX_CSV_BYTES = 64 * 2**30
"""The largest recording CSV ineid reads (64 GiB): an hour of a 7-joint arm at 4 kHz with its F/T sensor,
joint torques, motor currents and three IMUs (70 columns of 17 significant digits) is about 20 GB."""
MAX_COLUMNS = 10_000
"""The most columns a recording CSV's header may name: that arm needs 70, and a logger that writes every
signal of a controller a few hundred."""
MAX_ROWS = 100_000_000
"""The most data rows ineid reads from a recording CSV: about 7 hours at 4 kHz (the hour above is 14.4
million). The memory they need is checked too, before they are read."""
MAX_LINE_CHARS = 2**20
"""The longest line (characters) of a recording CSV: :data:`MAX_COLUMNS` cells of 100 characters. It bounds
every cell as well, and a file without line ends is refused after this many characters, not read whole."""
BLOCK_CHARS = 2**20
"""Characters read at a time: a block's text (about 1 MB) and its rows are all of the file that memory holds at once
beside the arrays (larger blocks read no faster)."""


@contextmanager
def csv_lines(path: Path) -> Iterator[Iterator[tuple[list[int], list[str]]]]:
    """The blocks of a CSV file's lines: ``(physical line numbers, lines)``, blank and ``#`` lines left out.

    The file is read as UTF-8 (a byte-order mark dropped), ``\\r\\n`` and ``\\r`` ending lines as ``\\n`` does.

    Raises:
        DatasetError: the file is not UTF-8 text or cannot be read, or a line is longer than
            :data:`MAX_LINE_CHARS` (also from the iteration).
    """
    try:
        with path.open(encoding="utf-8-sig") as fh:
            yield _line_blocks(fh, path)
    except UnicodeDecodeError as e:
        raise DatasetError(
            f"{path}: cannot be read as CSV text (not UTF-8: {e.reason}); save it as UTF-8 text"
        ) from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot be read ({e.strerror or e}); check the file and its permissions") from None


def _line_blocks(fh, path: Path) -> Iterator[tuple[list[int], list[str]]]:
    carry, first = "", 1  # the unfinished last line of the text read so far, and its line number
    while True:
        text = fh.read(BLOCK_CHARS)
        buf = carry + text
        cut = len(buf) if not text else buf.rfind("\n")
        if cut < 0:
            carry = buf
        else:
            lines = buf[:cut].split("\n")
            carry = buf[cut + 1 :]
            if lines and max(map(len, lines)) > MAX_LINE_CHARS:
                k = next(k for k, line in enumerate(lines) if len(line) > MAX_LINE_CHARS)
                _too_long(path, first + k)
            kept = [
                (k, line)
                for k, line in enumerate(lines, start=first)
                if line.strip() and not line.lstrip().startswith("#")
            ]
            first += len(lines)
            yield [k for k, _ in kept], [line for _, line in kept]
        if len(carry) > MAX_LINE_CHARS:
            _too_long(path, first)
        if not text:
            return


def _too_long(path: Path, line: int) -> NoReturn:
    raise DatasetError(
        f"{path}: line {line} is longer than {MAX_LINE_CHARS:,} characters "
        "(ineid.data.recordings.csv_rows.MAX_LINE_CHARS); a recording CSV has one row per line: check the file"
    )


def parse_header(line: str, number: int, path: Path) -> list[str]:
    """The header's column names, stripped and lower-cased.

    Raises:
        DatasetError: more than :data:`MAX_COLUMNS` columns, a name repeated, or no CSV.
    """
    try:
        header = [h.strip().lower() for h in next(csv.reader([line]))]
    except csv.Error as e:
        raise DatasetError(f"{path}: line {number} (the header) cannot be read as CSV ({e})") from None
    if len(header) > MAX_COLUMNS:
        raise DatasetError(
            f"{path}: the header names {len(header):,} columns, more than the {MAX_COLUMNS:,} ineid "
            "reads (ineid.data.recordings.csv_rows.MAX_COLUMNS); keep the columns of the recording (time, joints, "
            "wrench, torques, IMUs)"
        )
    seen: set[str] = set()
    for h in header:
        if h in seen and h:
            raise DatasetError(f"{path}: column {h[:80]!r} appears more than once in the header")
        seen.add(h)
    return header


@dataclass(frozen=True)
class Layout:
    """What the rows of a recording CSV hold.

    Attributes:
        path: the file, for messages.
        n_cells: the header's width: every row has this many cells.
        columns: the header index of each column read (column 0 of the arrays is the time).
        names: their names.
        streams: ``(lo, hi)`` of each stream's columns among ``names`` (the joints, the wrench, each
            IMU): a row holds all the cells of a stream or none.
    """

    path: Path
    n_cells: int
    columns: tuple[int, ...]
    names: tuple[str, ...]
    streams: tuple[tuple[int, int], ...]

    @property
    def limits(self) -> np.ndarray:
        """(len(names),) the largest magnitude of each column read."""
        return np.array([TIME_LIMIT] + [VALUE_LIMIT] * (len(self.names) - 1))


@dataclass
class Table:
    """The rows read: ``values`` (N, len(names)) with NaN in empty cells, ``present`` (N, streams) which streams
    each row holds, ``lines`` (N,) each row's physical line number."""

    values: np.ndarray
    present: np.ndarray
    lines: np.ndarray


def read_rows(
    blocks: Iterable[tuple[list[int], list[str]]],
    layout: Layout,
    size: int,
    progress: Callable[[int, int], None] | None = None,
) -> Table:
    """The data rows of ``blocks`` (the lines below the header) as arrays.

    Args:
        blocks: ``(line numbers, lines)`` (:func:`csv_lines`).
        layout: what the rows hold.
        size: the file's size in bytes (the number of rows is estimated from it and the first block).
        progress: ``progress(rows read, rows estimated)``.

    Raises:
        DatasetError: more than :data:`MAX_ROWS` rows (estimated before they are read, or counted), a
            bad row (:func:`parse_block`).
        ResourceError: the arrays would not fit in the memory available.
    """
    table, done, estimate = None, 0, 0
    for numbers, lines in blocks:
        if not lines:
            continue
        if table is None:  # the first block tells the size of a row: the memory and the row limit, before the rest
            estimate = max(len(lines), int(size * len(lines) / (sum(map(len, lines)) + len(lines))))
            _check_rows(estimate, layout, "about ")
            row_bytes = 8 * len(layout.names) + len(layout.streams) + 8
            require_memory(
                estimate * row_bytes,
                f"reading about {estimate:,} rows of {layout.path}",
                "import a shorter part of the recording",
            )
            # a quarter more than the estimate: pages never written are never given memory
            table = _empty(layout, int(1.25 * estimate) + len(lines))
        values, present = parse_block(numbers, lines, layout)
        _check_rows(done + len(lines), layout, "")
        if done + len(lines) > len(table.values):  # the first block's rows were longer than the rest
            table = _grown(table, 2 * (done + len(lines)), done)
        table.values[done : done + len(lines)] = values
        table.present[done : done + len(lines)] = present
        table.lines[done : done + len(lines)] = numbers
        done += len(lines)
        if progress is not None:
            progress(done, max(done, estimate))
    if progress is not None and done:
        progress(done, done)
    table = table or _empty(layout, 0)
    return Table(table.values[:done], table.present[:done], table.lines[:done])


def _empty(layout: Layout, n: int) -> Table:
    return Table(
        np.empty((n, len(layout.names))), np.empty((n, len(layout.streams)), dtype=bool), np.empty(n, dtype=np.int64)
    )


def _grown(table: Table, n: int, done: int) -> Table:
    out = Table(
        np.empty((n, table.values.shape[1])),
        np.empty((n, table.present.shape[1]), dtype=bool),
        np.empty(n, dtype=np.int64),
    )
    for k in ("values", "present", "lines"):
        getattr(out, k)[:done] = getattr(table, k)[:done]
    return out


def _check_rows(n: int, layout: Layout, about: str) -> None:
    if n > MAX_ROWS:
        raise DatasetError(
            f"{layout.path}: {about}{n:,} rows, more than the {MAX_ROWS:,} ineid reads from a recording "
            "(ineid.data.recordings.csv_rows.MAX_ROWS); import a shorter part of the recording"
        )


def parse_block(numbers: list[int], lines: list[str], layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """``(values, present)`` of a block of data lines (see :class:`Table`).

    Raises:
        DatasetError: a row of another width, a cell that is not a number, NaN, infinite (or beyond
            float64) or beyond its column's limit, an empty time, a row with some of a stream's cells
            only or with no stream; each message names the line, the column and the cell.
    """
    fast = _parse_fast(lines, layout)
    return fast if fast is not None else _parse_rows(numbers, lines, layout)


def _parse_fast(lines: list[str], layout: Layout) -> tuple[np.ndarray, np.ndarray] | None:
    """The block by NumPy, or None where :func:`_parse_rows` must look (it may find nothing wrong)."""
    text = "\n".join(lines)
    commas = layout.n_cells - 1
    if '"' in text or "n" in text or "N" in text or text.count(",") != commas * len(lines):
        return None
    if any(line.count(",") != commas for line in lines):
        return None
    # empty cells (no 'n' in the text: every NaN below is one) at a line's start, end, and in between
    text = ("\n" + text + "\n").replace(",,", ",nan,").replace(",,", ",nan,")
    text = text.replace("\n,", "\nnan,").replace(",\n", ",nan\n")
    try:
        values = np.loadtxt(
            text[1:-1].split("\n"),
            delimiter=",",
            usecols=layout.columns,
            dtype=np.float64,
            ndmin=2,
            comments=None,
            quotechar=None,
        )
    except ValueError:
        return None
    empty = np.isnan(values)
    present = np.empty((len(values), len(layout.streams)), dtype=bool)
    for s, (lo, hi) in enumerate(layout.streams):
        none = empty[:, lo:hi].all(axis=1)
        if (empty[:, lo:hi].any(axis=1) & ~none).any():
            return None
        present[:, s] = ~none
    if empty[:, 0].any() or not present.any(axis=1).all():
        return None
    if not (np.abs(np.where(empty, 0.0, values)) <= layout.limits).all():
        return None
    return values, present


def _parse_rows(numbers: list[int], lines: list[str], layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """The block row by row: the reference of :func:`_parse_fast`, and the messages."""
    path, names, limits = layout.path, layout.names, layout.limits
    values = np.full((len(lines), len(names)), np.nan)
    present = np.ones((len(lines), len(layout.streams)), dtype=bool)
    for i, (line, text) in enumerate(zip(numbers, lines, strict=True)):
        try:
            row = next(csv.reader([text]))
        except csv.Error as e:
            raise DatasetError(f"{path}: line {line} cannot be read as CSV ({e})") from None
        if len(row) != layout.n_cells:
            raise DatasetError(f"{path}: line {line} has {len(row)} cells, the header has {layout.n_cells}")
        cells = [row[c].strip() for c in layout.columns]
        empty = [not c for c in cells]
        for s, (lo, hi) in enumerate(layout.streams):
            if all(empty[lo:hi]):
                present[i, s] = False
            elif any(empty[lo:hi]):
                k = lo + empty[lo:hi].index(True)
                raise DatasetError(
                    f"{path}: line {line}, column {names[k]!r} is empty while others of its stream are not; "
                    "a row holds all the cells of each of its streams (the joints, the wrench, an IMU) or none"
                )
        if empty[0]:
            raise DatasetError(f"{path}: line {line}, column 'time' is empty")
        if not present[i].any():
            raise DatasetError(f"{path}: line {line} holds a time but no joint, wrench or IMU values")
        for k, cell in enumerate(cells):
            if cell:
                values[i, k] = _number(cell, line, names[k], limits[k], path)
    return values, present


def _number(cell: str, line: int, name: str, limit: float, path: Path) -> float:
    """A cell's value, or the one line that says why it is none."""
    try:
        v = float(cell)
    except ValueError:
        raise DatasetError(f"{path}: line {line}, column {name!r}: {cell[:40]!r} is not a number") from None
    if v != v or cell.lower().lstrip("+-") in ("inf", "infinity"):
        raise DatasetError(
            f"{path}: line {line}, column {name!r} is {cell}; values must be finite: drop or repair those rows"
        )
    if abs(v) > limit:
        beyond = "beyond the range of a float64" if abs(v) == float("inf") else f"beyond {limit:g} in magnitude"
        which = "TIME_LIMIT" if name == "time" else "VALUE_LIMIT"
        raise DatasetError(
            f"{path}: line {line}, column {name!r} is {cell[:40]}, {beyond}, more than any sensor or "
            f"clock gives (ineid.data.recordings.streams.{which}); a corrupt cell: repair or drop the row"
        )
    return v
