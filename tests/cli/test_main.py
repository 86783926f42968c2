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


def test_the_command_table_lists_every_command_module_with_its_help():
    """--help comes from COMMANDS without importing the commands: it must name every command
    module (and nothing else) with the module's own HELP line."""
    from nurbsmotion.cli import COMMANDS, command_modules

    modules = command_modules()
    assert {name: (COMMANDS[name].module, COMMANDS[name].help) for name in COMMANDS} == \
        {name: (module.__name__.rsplit(".", 1)[1], module.HELP) for name, module in modules.items()}


def test_help_lists_every_command(capsys):
    from nurbsmotion.cli import COMMANDS

    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = "".join(capsys.readouterr().out.split())  # argparse wraps the help lines (also at hyphens)
    for name, command in COMMANDS.items():
        assert "".join(f"{name} {command.help}".split()) in out


@pytest.mark.parametrize("argv", [["--help"], ["status"], ["-v", "hold"], ["jog", "X+1"], ["stop"],
                                  ["run", "examples/wang_table1.nc"], ["start", "wang_table1.nc"],
                                  ["programs", "add", "examples/wang_table1.nc"], ["programs", "list"],
                                  ["queue", "list"]])
def test_control_commands_import_neither_numpy_nor_the_planner(argv, tmp_path):
    """Only the named command's module is imported: a control client starts without numpy,
    the planner, the program reader, canopen or the configuration loader."""
    import subprocess
    import sys
    from pathlib import Path

    program = Path(__file__).resolve().parents[2] / "examples" / "wang_table1.nc"
    argv = [str(program) if a.endswith(".nc") else a for a in argv]
    if argv[-1] != "--help":
        argv += ["--socket", str(tmp_path / "no-daemon.sock")]
    heavy = ("numpy", "yaml", "canopen", "can", "nurbsmotion.planning", "nurbsmotion.program",
             "nurbsmotion.geometry", "nurbsmotion.config", "nurbsmotion.fieldbus", "nurbsmotion.sim")
    script = ("import sys\nfrom nurbsmotion.cli import main\n"
              "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
              f"print(sorted(m for m in sys.modules if m.startswith({heavy!r})))")
    done = subprocess.run([sys.executable, "-c", script, *argv], capture_output=True, text=True, timeout=60)
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout + done.stderr
