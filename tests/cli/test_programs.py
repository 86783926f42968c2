"""``nurbsmotion programs``, ``start`` and ``queue`` against a daemon with simulated drives
(this process): the outputs and exit codes of ``run``, one line per refusal."""

from __future__ import annotations

from pathlib import Path

import pytest

from nurbsmotion.cli import main
from tests.integration.daemon_helpers import daemon_in_process

SQUARE = "G21 G90\nG01 X4 Y3 F3000\nG01 X0 Y0\n"


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    with daemon_in_process(tmp_path_factory.mktemp("cli") / "data", "", "cli-lib") as d:
        yield d


def cli(daemon, capsys, *argv: str) -> tuple[int, str, str]:
    code = main([*argv, "--socket", str(daemon.config.control.socket)])
    out, err = capsys.readouterr()
    return code, out, err


def test_add_list_show_start_and_remove_a_program(daemon, tmp_path: Path, capsys):
    path = tmp_path / "square.nc"
    path.write_text(SQUARE)
    code, out, err = cli(daemon, capsys, "programs", "add", str(path), "--name", "sq.nc")
    assert (code, err) == (0, "")
    assert out == "added sq.nc: 2 blocks, lines 3 of 3 read, extent X 0..4 Y 0..3 Z 0..0 mm\n"
    code, out, _ = cli(daemon, capsys, "programs", "list")
    assert code == 0 and out.splitlines()[1].split()[:3] == ["sq.nc", str(len(SQUARE)), "2"]
    assert cli(daemon, capsys, "programs", "show", "sq.nc", "--text")[1] == SQUARE
    code, out, err = cli(daemon, capsys, "start", "sq.nc", "--no-progress")
    lines = out.splitlines()
    assert code == 0 and err == "", out + err
    assert lines[0] == "sq.nc: checked before (the library's check of it holds)"
    assert lines[1] == "sq.nc: 2 blocks, lines 3 of 3 read"
    assert lines[2].startswith("job ") and " completed: " in lines[2]
    assert cli(daemon, capsys, "programs", "remove", "sq.nc")[:2] == (0, "removed sq.nc\n")
    code, out, err = cli(daemon, capsys, "start", "sq.nc")
    assert (code, out) == (2, "")
    assert err == "nurbsmotion start: error: program 'sq.nc': not in the library (nurbsmotion programs list)\n"


def test_a_refused_program_is_one_line_per_error_and_exit_2(daemon, tmp_path: Path, capsys):
    path = tmp_path / "bad.nc"
    path.write_text("G21 G90\nG01 X4 Q1 F3000\nG01 X200\n")
    code, out, err = cli(daemon, capsys, "programs", "add", str(path))
    assert code == 2 and out == ""
    assert all(line.startswith("nurbsmotion programs: error: bad.nc:") for line in err.splitlines()), err
    code, _, err = cli(daemon, capsys, "programs", "add", str(path), "--name", "../x.nc")
    assert code == 2 and err.startswith("nurbsmotion programs: error: field 'name': program name '../x.nc'")
    assert "the library is empty" in cli(daemon, capsys, "programs", "list")[1]


def test_the_queue_commands(daemon, tmp_path: Path, capsys):
    path = tmp_path / "q.nc"
    path.write_text(SQUARE)
    assert cli(daemon, capsys, "programs", "add", str(path))[0] == 0
    assert cli(daemon, capsys, "queue", "pause")[0] == 0
    for _ in range(2):
        code, out, _ = cli(daemon, capsys, "queue", "add", "q.nc")
        assert code == 0
    lines = out.splitlines()
    assert lines[0] == "queue paused: paused by the operator" and len(lines) == 3
    second = int(lines[2].split()[2])
    code, out, _ = cli(daemon, capsys, "queue", "move", str(second), "1")
    assert code == 0 and out.splitlines()[1].split()[2] == str(second)
    code, _, err = cli(daemon, capsys, "queue", "remove", "999")
    assert code == 2 and err.startswith("nurbsmotion queue: error: field 'id': no queue entry 999")
    code, out, _ = cli(daemon, capsys, "queue", "clear")
    assert (code, out.splitlines()[1]) == (0, "(empty: nurbsmotion queue add NAME)")


def test_no_daemon_is_exit_3(tmp_path: Path, capsys):
    assert main(["programs", "list", "--socket", str(tmp_path / "none.sock")]) == 3
    assert main(["start", "x.nc", "--socket", str(tmp_path / "none.sock")]) == 3
    assert "no-daemon" not in capsys.readouterr().out


def test_a_daemon_that_takes_no_files_gets_the_text(tmp_path: Path):
    """cli.run.program_request: the open file first (protocol program_fd); a daemon that does
    not know the field (an older one) answers so, and gets the text instead."""
    from nurbsmotion.cli.run import program_request

    part = tmp_path / "part.nc"
    part.write_bytes(b"\xef\xbb\xbfG21 G90\nG01 X1 F600\n")
    sent: list[dict] = []

    class OlderDaemon:
        def request(self, cmd: str, files=(), **fields):
            sent.append({"cmd": cmd, "files": len(files), **fields})
            if "program_fd" in fields:
                return {"ok": False, "error": "field 'program_fd': unknown for command 'submit'; expected name, program"}
            return {"ok": True}

    with open(part, "rb") as program:
        assert program_request(OlderDaemon(), "submit", {"name": "part.nc"}, program) == {"ok": True}  # type: ignore[arg-type]
    assert sent == [{"cmd": "submit", "files": 1, "program_fd": 0, "name": "part.nc"},
                    {"cmd": "submit", "files": 0, "program": "G21 G90\nG01 X1 F600\n", "name": "part.nc"}]
