"""The gateway lowers its own priority at start-up (web.priority, ``web.nice``): applied to the
process that serves, configurable, and a bad value is one error line naming the field."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nurbsmotion.cli import main
from nurbsmotion.cli.web import add_arguments, settings_of
from nurbsmotion.web import app
from nurbsmotion.web.app import WebSettings
from nurbsmotion.web.priority import lower_own_priority

CHILD = ("import os; from nurbsmotion.web.priority import lower_own_priority; "
         "before = os.getpriority(os.PRIO_PROCESS, 0); now = lower_own_priority({increment}); "
         "print(before, now, os.getpriority(os.PRIO_PROCESS, 0))")


def niceness_in_child(increment: int) -> tuple[int, int, int]:
    """(niceness before, what lower_own_priority returned, niceness after) in a fresh process:
    a test must not lower the priority of the process running the other tests."""
    env = dict(os.environ, PYTHONPATH=str(Path(app.__file__).resolve().parents[2]))
    out = subprocess.run([sys.executable, "-c", CHILD.format(increment=increment)], env=env, check=True,
                         capture_output=True, text=True).stdout.split()
    before, returned, after = (int(v) for v in out)
    return before, returned, after


def test_the_increment_is_added_to_the_niceness_up_to_the_kernels_19():
    before, returned, after = niceness_in_child(3)
    assert returned == after == min(19, before + 3)
    before, returned, after = niceness_in_child(0)
    assert returned == after == before


@pytest.mark.parametrize("increment", [-1, 20])
def test_an_increment_outside_0_to_19_is_refused_naming_the_field(increment):
    with pytest.raises(ValueError, match=rf"^web.nice: must be 0-19, got {increment}$"):
        lower_own_priority(increment)


def test_the_gateway_lowers_its_priority_before_it_serves(monkeypatch):
    calls: list[str] = []
    monkeypatch.setattr(app, "lower_own_priority", lambda increment: calls.append(f"nice {increment}") or 19)
    monkeypatch.setattr(app.web, "run_app", lambda *a, **k: calls.append("serve"))
    app.run_gateway(WebSettings(socket="/nonexistent.sock", data_dir="/nonexistent", nice=7))
    assert calls == ["nice 7", "serve"]


def settings_from(tmp_path: Path, web: str) -> WebSettings:
    config = tmp_path / "m.yaml"
    config.write_text(f"axes: [{{name: X, node_id: 1}}]\n{web}")
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return settings_of(parser.parse_args(["--config", str(config)]))


def test_web_nice_defaults_to_10_and_is_read_from_the_yaml(tmp_path):
    assert settings_from(tmp_path, "").nice == 10
    assert settings_from(tmp_path, "web: {nice: 0}\n").nice == 0
    assert settings_from(tmp_path, "web: {nice: 19}\n").nice == 19


@pytest.mark.parametrize("value, problem", [("25", "must be <= 19, got 25"), ("-1", "must be >= 0, got -1"),
                                            ("2.5", "must be an integer, got 2.5"),
                                            ("high", "must be an integer, got 'high'")])
def test_a_bad_web_nice_is_one_error_line_and_nothing_starts(tmp_path, capsys, monkeypatch, value, problem):
    served: list[bool] = []
    monkeypatch.setattr(app, "run_gateway", lambda settings: served.append(True))
    config = tmp_path / "m.yaml"
    config.write_text(f"axes: [{{name: X, node_id: 1}}]\nweb: {{nice: {value}}}\n")
    assert main(["web", "--config", str(config)]) != 0
    assert capsys.readouterr().err.splitlines() == [f"nurbsmotion web: error: {config}:2: web.nice: {problem}"]
    assert served == []
