"""A raw program upload streamed into an unnamed file, never held as text (issue 25: the daemon
under 150 MB with a 10^6-line program; issue 22's upload path).

The HTTP body is read a chunk at a time into a memfd (``os.memfd_create``; an unlinked file
in the temp dir where there is none), counted against ``web.max_upload_mb`` and checked as
UTF-8 on the way with the CLI's own check (text_files.Utf8Check: the same message and byte
offset as ``nurbsmotion programs add FILE`` for the same file). The open file then goes to the
daemon as the CLI sends it (protocol ``program_fd``, SCM_RIGHTS: service.program_file spools
it) and is closed after: a refused upload leaves nothing behind.
"""

from __future__ import annotations

import os
import tempfile
from typing import BinaryIO

from aiohttp import web

from nurbsmotion.text_files import Utf8Check

CHUNK_BYTES = 1 << 16  # aiohttp's stream buffer is as large: the gateway holds about one chunk
MEMFD_NAME = "nurbsmotion-upload"  # as /proc/PID/fd shows it: /memfd:nurbsmotion-upload (deleted)


def unnamed_file() -> BinaryIO:
    """An empty read-write file with no name: a memfd, or an unlinked temporary file."""
    if hasattr(os, "memfd_create"):
        return os.fdopen(os.memfd_create(MEMFD_NAME, os.MFD_CLOEXEC), "w+b")
    return tempfile.TemporaryFile()


def too_large(max_bytes: int, size_bytes: int) -> web.HTTPRequestEntityTooLarge:
    """aiohttp's own refusal (app.errors_as_json words it as for any other body)."""
    return web.HTTPRequestEntityTooLarge(max_size=max_bytes, actual_size=size_bytes)


async def upload_file(request: web.Request, where: str) -> BinaryIO:
    """The request's body in an unnamed file (module docstring); HTTPRequestEntityTooLarge over
    the limit (the app's client_max_size: web.max_upload_mb; refused from Content-Length
    before any is read), InputError ``where: not a UTF-8 text file (... at byte N)`` for a
    body that is not UTF-8. Nothing is kept when it raises."""
    max_bytes = request.client_max_size
    declared = request.content_length
    if declared is not None and declared > max_bytes:
        raise too_large(max_bytes, declared)
    out = unnamed_file()
    try:
        check, size = Utf8Check(), 0
        async for chunk in request.content.iter_chunked(CHUNK_BYTES):
            size += len(chunk)
            if size > max_bytes:
                raise too_large(max_bytes, size)
            check.feed(chunk, where)
            out.write(chunk)
        check.feed(b"", where, final=True)
        out.flush()
    except BaseException:
        out.close()
        raise
    return out
