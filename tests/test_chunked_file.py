"""chunked_file: chunks formatted elsewhere, written one system call each."""

import io

from nurbsmotion.chunked_file import take_text, write_all, write_file


class ShortWrites(io.RawIOBase):
    """An unbuffered file that takes at most 3 bytes a call (as a pipe or a full disk may)."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.calls = 0

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:  # type: ignore[override]
        self.calls += 1
        taken = bytes(b[:3])
        self.data += taken
        return len(taken)


def test_every_chunk_is_written_whole_in_order_even_when_a_call_takes_part():
    out = ShortWrites()
    assert write_all(out, [b"abcdefg", b"", b"hi"]) == 9  # type: ignore[arg-type]
    assert bytes(out.data) == b"abcdefghi" and out.calls == 4


def test_a_file_with_its_folders_and_text_taken_chunk_by_chunk(tmp_path):
    text = io.StringIO()
    text.write("é,1\n")
    first = take_text(text)
    text.write("2\n")
    path = write_file(tmp_path / "a" / "b.csv", [first, take_text(text)])
    assert path.read_bytes() == "é,1\n2\n".encode() and text.getvalue() == ""
