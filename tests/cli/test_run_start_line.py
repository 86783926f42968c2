"""``nurbsmotion run --start-line N``: the option reaches the submit request; a refusal is
printed as the daemon's one line."""

from __future__ import annotations

import argparse

import pytest

from nurbsmotion.cli import run as run_cli


class _RefusingClient:
    def __init__(self) -> None:
        self.requests: list[tuple[str, dict]] = []

    def request(self, cmd: str, **fields):
        self.requests.append((cmd, fields))
        return {"ok": False, "error": "part.nc:40: past the end of the program: the file has 9 lines"}


def _run(monkeypatch, tmp_path, *argv: str) -> tuple[int, _RefusingClient]:
    program = tmp_path / "part.nc"
    program.write_text("G1 X1 F100\n")
    parser = argparse.ArgumentParser()
    run_cli.add_arguments(parser)
    args = parser.parse_args([*argv, str(program)])
    args.command = "run"
    client = _RefusingClient()
    monkeypatch.setattr(run_cli, "with_client", lambda _args, body: body(client))
    return run_cli.run(args), client


def test_start_line_is_sent_with_the_submit(monkeypatch, tmp_path, capsys):
    code, client = _run(monkeypatch, tmp_path, "--start-line", "40")
    assert code == 2
    assert client.requests[0][0] == "submit" and client.requests[0][1]["start_line"] == 40
    assert capsys.readouterr().err == "nurbsmotion run: error: part.nc:40: past the end of the program: the file has 9 lines\n"


def test_without_the_option_no_start_line_is_sent(monkeypatch, tmp_path):
    _, client = _run(monkeypatch, tmp_path)
    assert "start_line" not in client.requests[0][1]


def test_a_bad_start_line_is_an_argument_error(capsys):
    parser = argparse.ArgumentParser()
    run_cli.add_arguments(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(["--start-line", "0", "part.nc"])
    assert "argument --start-line: must be a line number >= 1, got '0'" in capsys.readouterr().err
