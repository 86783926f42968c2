"""A text file the user names (a program), read the one way ``check`` and ``run`` share:
UTF-8 with an optional BOM (not part of line 1); anything else is one error line naming
the file. Light on purpose: ``run`` reads its program before importing any reader."""

from __future__ import annotations

import codecs
from pathlib import Path
from typing import BinaryIO

from nurbsmotion.errors import InputError

CHUNK_BYTES = 1 << 20


class Utf8Check:
    """UTF-8 check of a file read in chunks, without keeping its text; the error names the
    byte (counted over the chunks fed) as read_text_file's does."""

    def __init__(self) -> None:
        self._decoder = codecs.getincrementaldecoder("utf-8")()
        self._offset = 0

    def feed(self, chunk: bytes, where: str, final: bool = False) -> None:
        """InputError ``where: not a UTF-8 text file (...)`` when ``chunk`` breaks the encoding."""
        try:
            self._decoder.decode(chunk, final=final)
        except UnicodeDecodeError as err:
            raise InputError(where, f"not a UTF-8 text file ({err.reason} at byte {self._offset + err.start})") from None
        self._offset += len(chunk)


def read_text_file(path: str | Path) -> str:
    """The file's text; InputError ``path: not a UTF-8 text file (...)`` or ``cannot read: ...``."""
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise InputError(str(path), f"not a UTF-8 text file ({err.reason} at byte {err.start})") from None
    except OSError as err:
        raise InputError(str(path), f"cannot read: {err.strerror or err}") from None


def open_text_file(path: str | Path) -> BinaryIO:
    """The file open for reading, checked as read_text_file reads it (the same errors) a
    megabyte at a time without keeping its text: ``run`` and ``programs add`` send the open
    file to the daemon (service.program_file)."""
    try:
        src = open(path, "rb")
    except OSError as err:
        raise InputError(str(path), f"cannot read: {err.strerror or err}") from None
    check = Utf8Check()
    try:
        for chunk in iter(lambda: src.read(CHUNK_BYTES), b""):
            check.feed(chunk, str(path))
        check.feed(b"", str(path), final=True)
    except InputError:
        src.close()
        raise
    except OSError as err:
        src.close()
        raise InputError(str(path), f"cannot read: {err.strerror or err}") from None
    src.seek(0)
    return src
