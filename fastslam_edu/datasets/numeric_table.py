"""Reading a text table of numbers, every row checked, errors naming the file and the line.

:func:`read_numeric_table` reads the MR.CLAM ``.dat`` files (whitespace separated, ``#`` comments) and the
1 Hz groundtruth CSV files: ``numpy.loadtxt`` first (fast), then, when it or a check fails, the file once more line
by line to say which line is wrong (wrong column count, a field that is not a number, NaN or infinity, a
non-integer id, time going backwards). :mod:`fastslam_edu.datasets.mrclam` builds its readers on it.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

__all__ = ["read_numeric_table", "line_of_row"]


def _data_lines(path: Path, delimiter: str | None, skip_header: int) -> Iterator[tuple[int, list[str]]]:
    """Yield ``(line number, fields)`` of every data line, the way np.loadtxt sees them.

    Line numbers count from 1; the first ``skip_header`` lines, text after
    ``#`` and blank lines are skipped.
    """
    with open(path, encoding="utf-8", errors="replace") as f:
        for lineno, line in enumerate(f, start=1):
            if lineno <= skip_header:
                continue
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            fields = text.split(delimiter) if delimiter else text.split()
            yield lineno, [s.strip() for s in fields]


def _raise_at_bad_line(path: Path, columns: Sequence[str], delimiter: str | None,
                       skip_header: int, cause: Exception) -> None:
    """Scan ``path`` line by line and raise a ValueError naming the first bad line."""
    ncols = len(columns)
    for lineno, fields in _data_lines(path, delimiter, skip_header):
        if len(fields) != ncols:
            raise ValueError(
                f"{path}, line {lineno}: expected {ncols} columns ({', '.join(columns)}), "
                f"found {len(fields)}: {' '.join(fields)!r}"
            ) from None
        for name, s in zip(columns, fields):
            try:
                float(s)
            except ValueError:
                raise ValueError(
                    f"{path}, line {lineno}: {name} field {s!r} is not a number"
                ) from None
    raise ValueError(f"{path}: could not be parsed ({cause})") from cause


def line_of_row(path: Path, row: int, delimiter: str | None, skip_header: int) -> int:
    """File line number (from 1) of data row ``row`` (from 0)."""
    for i, (lineno, _) in enumerate(_data_lines(path, delimiter, skip_header)):
        if i == row:
            return lineno
    raise IndexError(row)  # pragma: no cover - row comes from the parsed array


def read_numeric_table(path: str | Path, columns: Sequence[str], *, delimiter: str | None = None,
                       skip_header: int = 0, time_column: bool = False,
                       integer_columns: Iterable[str] = ()) -> np.ndarray:
    """Read a text table of numbers, checking every row.

    Fast path: :func:`numpy.loadtxt` (``#`` starts a comment, blank lines are
    skipped). When it fails, or a check below fails, the file is scanned line
    by line to name the offending line in the error.

    Parameters
    ----------
    path : str or Path
    columns : sequence of str
        Expected column names (their count is checked; names go into messages).
    delimiter : str or None
        None for any whitespace (the ``.dat`` files), ``","`` for CSV.
    skip_header : int
        Lines to skip before parsing (a CSV header line; the ``.dat`` headers
        are comments anyway).
    time_column : bool
        If True, column 0 is a time that must be non-decreasing.
    integer_columns : iterable of str
        Columns whose values must be whole numbers (subject, barcode).

    Returns
    -------
    ndarray, shape (n_rows, len(columns)), float

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        ``"<path>, line <n>: ..."`` for a wrong column count, a non-numeric,
        NaN or infinite field, a non-integer id, or a time smaller than the
        previous row's; ``"<path>: no data rows ..."`` for an empty table.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MR.CLAM file not found: {path}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # loadtxt warns on an empty file; we raise below
            table = np.loadtxt(path, comments="#", delimiter=delimiter, skiprows=skip_header,
                               ndmin=2, dtype=float, encoding="utf-8")
    except ValueError as exc:  # wrong column count, text in a number field, bad encoding
        _raise_at_bad_line(path, columns, delimiter, skip_header, exc)
    if table.shape[0] == 0:
        raise ValueError(f"{path}: no data rows (every line is a header, comment or blank)")

    def line(row: int) -> int:
        return line_of_row(path, row, delimiter, skip_header)

    if table.shape[1] != len(columns):
        raise ValueError(
            f"{path}, line {line(0)}: expected {len(columns)} columns ({', '.join(columns)}), "
            f"found {table.shape[1]}"
        )
    bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
    if bad.size:
        r = int(bad[0])
        c = int(np.flatnonzero(~np.isfinite(table[r]))[0])
        raise ValueError(f"{path}, line {line(r)}: {columns[c]} is {table[r, c]} (NaN and inf are not allowed)")
    for name in integer_columns:
        c = list(columns).index(name)
        bad = np.flatnonzero(table[:, c] != np.round(table[:, c]))
        if bad.size:
            r = int(bad[0])
            raise ValueError(f"{path}, line {line(r)}: {name} {table[r, c]} is not a whole number")
    if time_column:
        back = np.flatnonzero(np.diff(table[:, 0]) < 0)
        if back.size:
            r = int(back[0]) + 1
            raise ValueError(
                f"{path}, line {line(r)}: time {float(table[r, 0])!r} s goes backwards "
                f"(line {line(r - 1)} has {float(table[r - 1, 0])!r} s); the file must be in time order"
            )
    return table
