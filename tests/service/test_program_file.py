"""service.program_file: a program held as a daemon-owned file, its SHA-256 the text's."""

from __future__ import annotations

import os

import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.service.checked_store import text_digest
from nurbsmotion.service.program_file import ProgramFile, clear_spool, file_stamp, requested_program, snapshot, spool
from nurbsmotion.text_files import open_text_file, read_text_file

TEXT = "G21 G90 (é)\nG01 X4 Y3 F3000\n" * 3000  # ~90 kB


def spooled(tmp_path, data: bytes, max_bytes: int = 1 << 30) -> ProgramFile:
    source = tmp_path / "part.nc"
    source.write_bytes(data)
    fd = os.open(source, os.O_RDONLY)
    try:
        return spool(fd, tmp_path / "data", "program 'part.nc'", max_bytes)
    finally:
        os.close(fd)


@pytest.mark.parametrize("prefix", [b"", b"\xef\xbb\xbf"])
def test_a_spooled_file_holds_the_text_run_would_send_and_its_digest(tmp_path, prefix, monkeypatch):
    monkeypatch.setattr("nurbsmotion.service.program_file.CHUNK_BYTES", 1000)  # a character split across chunks
    program = spooled(tmp_path, prefix + TEXT.encode())
    assert program.path.parent == tmp_path / "data" / "spool"
    assert program.read_text() == read_text_file(tmp_path / "part.nc") == TEXT
    assert program.sha256 == text_digest(TEXT) and program.size_bytes == len(TEXT.encode())
    program.discard()
    assert list((tmp_path / "data" / "spool").iterdir()) == []
    left = spooled(tmp_path, TEXT.encode())  # a daemon that died mid-start
    clear_spool(tmp_path / "data")
    assert not left.path.exists()
    clear_spool(tmp_path / "nothing")  # no spool yet: nothing to do


def test_a_file_not_utf8_too_large_or_not_regular_is_refused_and_leaves_nothing(tmp_path):
    with pytest.raises(InputError) as info:
        spooled(tmp_path, b"G21\n\x89PNG\r\n")
    assert str(info.value) == "program 'part.nc': not a UTF-8 text file (invalid start byte at byte 4)"
    with pytest.raises(InputError) as info:
        spooled(tmp_path, TEXT.encode(), max_bytes=1024 * 1024 // 16)
    assert str(info.value) == "program 'part.nc': larger than the 0.0625 MB limit (web.max_upload_mb)"
    read, write = os.pipe()
    try:
        with pytest.raises(InputError) as info:
            spool(read, tmp_path / "data", "program 'x.nc'", 1000)
        assert str(info.value) == "program 'x.nc': the descriptor sent is not a regular file"
    finally:
        os.close(read)
        os.close(write)
    assert list((tmp_path / "data" / "spool").iterdir()) == []


def test_the_client_check_gives_read_text_files_errors(tmp_path):
    part = tmp_path / "part.nc"
    part.write_bytes(b"G21\n\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(InputError) as opened:
        open_text_file(part)
    with pytest.raises(InputError) as read:
        read_text_file(part)
    assert str(opened.value) == str(read.value)
    with pytest.raises(InputError) as missing:
        open_text_file(tmp_path / "none.nc")
    assert str(missing.value).startswith(f"{tmp_path / 'none.nc'}: cannot read:")


def test_a_snapshot_takes_the_recorded_digest_only_for_the_very_file_recorded(tmp_path):
    library = tmp_path / "part.nc"
    library.write_text(TEXT)
    stamp = file_stamp(library)
    trusted = snapshot(library, tmp_path / "data", stamp, "recorded")
    assert trusted.sha256 == "recorded" and trusted.read_text() == TEXT  # not read: the library's record
    library.write_text(TEXT.replace("X4", "X5"))  # edited in place: the same inode, the link sees it
    edited = snapshot(library, tmp_path / "data", stamp, "recorded")
    assert edited.sha256 == text_digest(TEXT.replace("X4", "X5"))
    library.unlink()
    library.write_text(TEXT)  # replaced (as the library replaces): another inode
    replaced = snapshot(library, tmp_path / "data", stamp, "recorded")
    assert replaced.sha256 == text_digest(TEXT)
    for program in (trusted, edited, replaced):
        program.discard()


def test_a_request_names_its_program_by_text_or_by_a_descriptor_sent_along(tmp_path):
    with requested_program({"program": TEXT}, (), tmp_path, 1 << 20, "limit") as text:
        assert text == TEXT
    (tmp_path / "part.nc").write_text(TEXT)
    fd = os.open(tmp_path / "part.nc", os.O_RDONLY)
    try:
        with requested_program({"name": "part.nc", "program_fd": 0}, (fd,), tmp_path, 1 << 20, "limit") as program:
            assert isinstance(program, ProgramFile) and program.read_text() == TEXT
        assert not program.path.exists()  # discarded once served
        for index in (1, 0.5, -1):
            with pytest.raises(InputError) as info:
                with requested_program({"program_fd": index}, (fd,), tmp_path, 1 << 20, "limit"):
                    pass
            assert str(info.value) == f"field 'program_fd': no file descriptor {index!r} came with the request (1 did)"
    finally:
        os.close(fd)
