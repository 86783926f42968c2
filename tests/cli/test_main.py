"""The command itself: bad arguments give one line and exit code 2, never a traceback."""

import pytest

from nurbsmotion import __version__
from nurbsmotion.cli import EXIT_BAD_INPUT, main


def test_unknown_command_is_one_line_exit_2(capsys):
    with pytest.raises(SystemExit) as info:
        main(["no-such-command"])
    assert info.value.code == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no-such-command" in err[0]


def test_no_command_prints_help_and_exit_2(capsys):
    assert main([]) == EXIT_BAD_INPUT
    assert "usage: nurbsmotion" in capsys.readouterr().err


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert __version__ in capsys.readouterr().out
