"""Where a measurement table's rows come from: a text file as a lab's tools wrote it, or the
first sheet of an Excel workbook (``.xlsx``, read through openpyxl, an optional dependency).

Text: UTF-8 (with or without a byte-order mark), UTF-16 (with a byte-order mark, or plain
ASCII text in UTF-16 without one: Excel's "Unicode text"), else Windows-1252, else Latin-1;
any line endings; the separator is the one of ``,``, ``;`` and tab that the header line (the
first that is not blank or a comment) uses most.

Each source yields its non-blank rows as ``(line, cells, comment)``: the line of the file (the
row of the sheet) that messages name, the cells as text, and whether the row is a comment (its
first character ``#``; its cells are then those after the ``#``). Lines are tokenised one by one
with the standard library's ``csv`` reader rather than ``pandas.read_csv``: every message names
the line of the file, and ``read_csv`` renumbers rows past comments and blank lines, pads a
short row silently and drops a commented-out capsule row that must be named.
"""
from __future__ import annotations

import codecs
import csv
import importlib
import io
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import date, datetime, time
from pathlib import Path

from capsmech.errors import CapsmechError
from capsmech.io.text import ENCODINGS, read_bytes, split_lines

#: A non-blank row: (line of the file or row of the sheet, cells, whether it is a comment).
Row = tuple[int, list[str], bool]
#: Separators tried on the header line.
SEPARATORS = (",", ";", "\t")
ZIP_MAGIC = b"PK\x03\x04"                   # .xlsx (and .ods: refused with a hint)
OLE_MAGIC = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"  # .xls (Excel 97-2003)


@dataclass(frozen=True)
class Source:
    """A table's rows and how its numbers are written.

    Attributes
    ----------
    rows : iterator of Row
        The non-blank rows, in order.
    separator : str
        The text file's separator, or ``""`` for a workbook.
    """

    rows: Iterator[Row]
    separator: str

    @property
    def decimal_comma(self) -> bool:
        """Whether ``0,5`` is a decimal comma: wherever a comma cannot be a field break."""
        return self.separator != ","


def open_source(path: Path, limit: int, what: str, error: type[CapsmechError]) -> Source:
    """The rows of a measurement file (text or workbook), at most ``limit`` bytes of it read.

    Raises
    ------
    CapsmechError
        ``error``, naming the file (and the line where there is one): unreadable, over the
        limit, binary, an ``.xls`` or unreadable workbook, or a workbook without openpyxl.
    """
    data = read_bytes(path, limit, what, error)
    if data.startswith(ZIP_MAGIC):
        return Source(_sheet_rows(path, data, error), "")
    if data.startswith(OLE_MAGIC):
        raise error(f"{path}: an Excel 97-2003 workbook (.xls), which capsmech does not read: save it as .xlsx or CSV")
    lines = split_lines(_decode(path, data, what, error))
    separator = _separator(lines)
    return Source(_text_rows(path, lines, separator, error), separator)


def _bomless_utf16(data: bytes) -> str | None:
    """``'utf-16-le'`` or ``'-be'`` when the file starts as ASCII text in UTF-16 without a byte-order mark."""
    head = data[:1024]
    if len(head) < 4 or len(head) % 2:
        return None
    for encoding, text_bytes, zeros in (("utf-16-le", head[0::2], head[1::2]), ("utf-16-be", head[1::2], head[0::2])):
        if zeros.count(0) == len(zeros) and 0 not in text_bytes:
            return encoding
    return None


def _decode(path: Path, data: bytes, what: str, error: type[CapsmechError]) -> str:
    """The file's text; a NUL byte outside UTF-16 (or a NUL character in it) marks a binary file."""
    encoding = "utf-16" if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)) else _bomless_utf16(data)
    if encoding is not None:
        try:
            text = data.decode(encoding)
        except UnicodeDecodeError as err:
            raise error(f"{path}: UTF-16 text broken at byte {err.start} ({err.reason})") from None
    else:
        text = next(_decodings(data))
    nul = text.find("\x00")
    if nul >= 0:
        line = text.count("\n", 0, nul) + text.count("\r", 0, nul) - text.count("\r\n", 0, nul) + 1
        raise error(f"{path}:{line}: a NUL byte: a binary file, not a {what} (text)")
    return text


def _decodings(data: bytes) -> Iterator[str]:
    for encoding in ENCODINGS:       # Latin-1, the last, decodes every byte
        try:
            yield data.decode(encoding)
        except UnicodeDecodeError:
            continue


def _is_comment(line: str) -> bool:
    """A comment line: its first character after blanks is ``#`` (a quoted ``"#id"`` is not)."""
    return line.lstrip().startswith("#")


def _separator(lines: list[str]) -> str:
    """The separator the header line (the first that is not blank or a comment) uses most."""
    for text in lines:
        if text.strip(",;\t \"") and not _is_comment(text):
            return max(SEPARATORS, key=text.count)       # ties (none at all) go to ","
    return ","


def _cells(path: Path, text: str, separator: str, number: int, error: type[CapsmechError]) -> list[str]:
    """One line's cells; a cell beyond the csv module's limit (128 kB) is no measurement."""
    try:
        return next(csv.reader([text], delimiter=separator), [])
    except csv.Error as err:
        raise error(f"{path}:{number}: {err} (no field of a measurement file is that long)") from None


def _text_rows(path: Path, lines: list[str], separator: str, error: type[CapsmechError]) -> Iterator[Row]:
    for number, text in enumerate(lines, start=1):
        if not text.strip(" \t" + separator):
            continue
        if _is_comment(text):
            yield number, _cells(path, text.lstrip()[1:], separator, number, error), True
            continue
        row = _cells(path, text, separator, number, error)
        if any(cell.strip() for cell in row):
            yield number, row, False


def _sheet_rows(path: Path, data: bytes, error: type[CapsmechError]) -> Iterator[Row]:
    """The first sheet's rows, numbered as the spreadsheet numbers them."""
    try:
        # Imported by name: an optional dependency without type stubs.
        openpyxl = importlib.import_module("openpyxl")
    except ImportError:
        raise error(f"{path}: an Excel workbook; reading it needs openpyxl (pip install openpyxl), "
                    "or save the sheet as CSV") from None
    try:
        book = openpyxl.load_workbook(io.BytesIO(data), read_only=True, data_only=True)
        sheet = book.worksheets[0]
    except Exception as err:  # noqa: BLE001 - openpyxl and zipfile raise many kinds on a damaged file
        raise error(f"{path}: not a readable .xlsx workbook ({type(err).__name__}: {err}); "
                    "save the sheet as .xlsx or CSV") from None
    return _sheet_cells(path, sheet.iter_rows(values_only=True), error)


def _sheet_cells(path: Path, rows: Iterator[tuple[object, ...]], error: type[CapsmechError]) -> Iterator[Row]:
    number = 0
    try:
        for number, values in enumerate(rows, start=1):
            cells = [_cell_text(value) for value in values]
            if not any(cell.strip() for cell in cells):
                continue
            if cells[0].lstrip().startswith("#"):
                yield number, [cells[0].lstrip()[1:], *cells[1:]], True
            else:
                yield number, cells, False
    except CapsmechError:
        raise
    except Exception as err:  # noqa: BLE001 - a damaged sheet fails while it is read
        raise error(f"{path}:{number + 1}: the sheet cannot be read ({type(err).__name__}: {err})") from None


def _cell_text(value: object) -> str:
    """A sheet cell as the CSV would hold it (a float's repr reads back to the same float)."""
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (datetime, date, time)):
        return value.isoformat()
    return str(value)
