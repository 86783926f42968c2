"""The gateway lowers its own priority and keeps off the daemon's real-time CPU at start-up
(web.priority, ``web.nice``, ``web.cpus``): applied to the process that serves, configurable,
and a bad value is one error line naming the field."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nurbsmotion.cli import main
from nurbsmotion.cli.web import add_arguments, settings_of
from nurbsmotion.web import app
from nurbsmotion.web.app import WebSettings
from nurbsmotion.config import GatewayCpus
from nurbsmotion.errors import InputError
from nurbsmotion.web.priority import cpus_for, lower_own_priority

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


def test_the_gateway_places_its_threads_and_lowers_its_priority_before_it_serves(monkeypatch):
    calls: list[str] = []
    monkeypatch.setattr(app, "place_own_threads", lambda cpus: calls.append(f"cpus {cpus}") or {0})
    monkeypatch.setattr(app, "lower_own_priority", lambda increment: calls.append(f"nice {increment}") or 19)
    monkeypatch.setattr(app.web, "run_app", lambda *a, **k: calls.append("serve"))
    app.run_gateway(WebSettings(socket="/nonexistent.sock", data_dir="/nonexistent", nice=7, cpus=(0,)))
    assert calls == ["cpus (0,)", "nice 7", "serve"]


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


# ---------------------------------------------------------------- web.cpus
def test_web_cpus_defaults_to_auto_and_reads_a_word_or_a_list(tmp_path):
    assert settings_from(tmp_path, "").cpus is GatewayCpus.AUTO
    assert settings_from(tmp_path, "web: {cpus: all}\n").cpus is GatewayCpus.ALL
    assert settings_from(tmp_path, "web: {cpus: [1, 0, 1]}\n").cpus == (0, 1)


@pytest.mark.parametrize("web, problem", [
    ("nice: 25", "web.nice: must be <= 19, got 25"), ("nice: -1", "web.nice: must be >= 0, got -1"),
    ("nice: 2.5", "web.nice: must be an integer, got 2.5"), ("nice: high", "web.nice: must be an integer, got 'high'"),
    ("cpus: some", "web.cpus: must be one of auto, all, got 'some'"),
    ("cpus: []", "web.cpus: must list at least one CPU (or be auto or all)"),
    ("cpus: [0, -1]", "web.cpus[1]: must be >= 0, got -1"),
    ("cpus: [0.5]", "web.cpus[0]: must be an integer, got 0.5")])
def test_a_bad_web_nice_or_cpus_is_one_error_line_and_nothing_starts(tmp_path, capsys, monkeypatch, web, problem):
    served: list[bool] = []
    monkeypatch.setattr(app, "run_gateway", lambda settings: served.append(True))
    config = tmp_path / "m.yaml"
    config.write_text(f"axes: [{{name: X, node_id: 1}}]\nweb: {{{web}}}\n")
    assert main(["web", "--config", str(config)]) != 0
    assert capsys.readouterr().err.splitlines() == [f"nurbsmotion web: error: {config}:2: {problem}"]
    assert served == []


def test_auto_is_every_cpu_but_the_realtime_one_and_all_leaves_them():
    assert cpus_for(GatewayCpus.AUTO, {0, 1, 2, 3}, 4) == {0, 1, 2}
    assert cpus_for(GatewayCpus.AUTO, {0, 2}, 4) == {0}  # started with taskset: the daemon's rule on its CPUs
    assert cpus_for(GatewayCpus.AUTO, {0}, 1) == {0}  # one CPU: nothing to keep off
    assert cpus_for(GatewayCpus.ALL, {0, 1}, 2) == {0, 1}
    assert cpus_for((1,), {0}, 2) == {1}


def test_a_cpu_the_machine_does_not_have_is_one_error_naming_the_field(tmp_path, capsys, monkeypatch):
    with pytest.raises(InputError, match=r"^web.cpus: no CPU 4 on this machine \(its CPUs are 0-1\)$"):
        cpus_for((0, 4), {0, 1}, 2)
    served: list[bool] = []
    monkeypatch.setattr(app.web, "run_app", lambda *a, **k: served.append(True))
    config = tmp_path / "m.yaml"
    config.write_text(f"axes: [{{name: X, node_id: 1}}]\nweb: {{cpus: [{os.cpu_count()}]}}\n")
    assert main(["web", "--config", str(config)]) != 0
    assert capsys.readouterr().err.splitlines() == [
        f"nurbsmotion web: error: web.cpus: no CPU {os.cpu_count()} on this machine "
        f"(its CPUs are 0-{(os.cpu_count() or 1) - 1})"]
    assert served == []


PLACED = ("import json, os, threading; from nurbsmotion.config import GatewayCpus; "
          "from nurbsmotion.web.priority import place_own_threads; placed = place_own_threads(GatewayCpus.AUTO); "
          "seen = {}; t = threading.Thread(target=lambda: seen.update(later=sorted(os.sched_getaffinity(0)))); "
          "t.start(); t.join(); print(json.dumps({'placed': sorted(placed), **seen}))")


def test_the_gateway_and_every_thread_it_starts_later_keep_off_the_realtime_cpu():
    if not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs two CPUs and sched_setaffinity")
    env = dict(os.environ, PYTHONPATH=str(Path(app.__file__).resolve().parents[2]))
    done = subprocess.run([sys.executable, "-c", PLACED], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    cpus = sorted(os.sched_getaffinity(0))
    assert json.loads(done.stdout) == {"placed": cpus[:-1], "later": cpus[:-1]}
