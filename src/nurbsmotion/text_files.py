"""A text file the user names (a program), read the one way ``check`` and ``run`` share:
UTF-8 with an optional BOM (not part of line 1); anything else is one error line naming
the file. Light on purpose: ``run`` reads its program before importing any reader."""

from __future__ import annotations

from pathlib import Path

from nurbsmotion.errors import InputError


def read_text_file(path: str | Path) -> str:
    """The file's text; InputError ``path: not a UTF-8 text file (...)`` or ``cannot read: ...``."""
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise InputError(str(path), f"not a UTF-8 text file ({err.reason} at byte {err.start})") from None
    except OSError as err:
        raise InputError(str(path), f"cannot read: {err.strerror or err}") from None
