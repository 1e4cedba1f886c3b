"""Reading the text tables researchers bring (QSM cylinder tables, tree lists, trajectories).

Spreadsheets and MATLAB on Windows write single-byte text (Windows-1252) or UTF-16 ("Unicode text"),
not UTF-8. The values these tables hold are ASCII, so where a file is not UTF-8 it is read as Latin-1,
every byte one character: only free text, such as a comment or a column the reader ignores, can read
differently from what its author saw. A file holding NUL bytes without a UTF-16 byte order mark is
binary.
"""

from __future__ import annotations

import codecs
from pathlib import Path


class NotTextError(ValueError):
    """The file is binary, not a text table."""


def read_text(path) -> str:
    """The text of ``path``: UTF-8 (a byte order mark dropped), UTF-16 with its byte order mark, else
    Latin-1.

    :raises NotTextError: NUL bytes in a file without a UTF-16 byte order mark.
    :raises OSError: the file cannot be read.
    """
    data = Path(path).read_bytes()
    if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        try:
            return data.decode("utf-16")
        except UnicodeDecodeError:
            raise NotTextError(f"{path}: not UTF-16 text after its byte order mark") from None
    if b"\0" in data:
        raise NotTextError(f"{path}: a binary file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


SEMICOLONS = ("separated by ';' (a spreadsheet set to decimal commas): save it as CSV with ',' between cells and "
              "'.' in numbers")


def semicolon_separated(header: list[str]) -> bool:
    """Whether a CSV header split at commas is one cell holding semicolons (what a spreadsheet set to
    decimal commas writes)."""
    return len(header) == 1 and ";" in header[0]


def repeated(header: list[str], names) -> str | None:
    """The first of ``names`` that ``header`` holds more than once (a reader would take one copy), or None."""
    return next((c for c in names if header.count(c) > 1), None)
