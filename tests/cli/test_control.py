"""Where the control commands find the daemon: flags, environment, default."""

import argparse
from pathlib import Path

import pytest

from nurbsmotion.cli import main
from nurbsmotion.cli._control import socket_path
from nurbsmotion.config import ControlConfig

CONFIG = "axes:\n  - {name: X, node_id: 1, counts_per_mm: 100}\ncontrol: {socket: %s}\n"


@pytest.fixture
def configs(tmp_path, monkeypatch):
    monkeypatch.delenv("NURBSMOTION_SOCKET", raising=False)
    monkeypatch.delenv("NURBSMOTION_CONFIG", raising=False)
    paths = {}
    for name in ("a", "b"):
        paths[name] = tmp_path / f"{name}.yaml"
        paths[name].write_text(CONFIG % (tmp_path / f"{name}.sock"))
    return tmp_path, paths


def _args(**kw):
    return argparse.Namespace(**{"socket": None, "config": None, **kw})


def test_flags_win_then_the_socket_variable_then_the_config_variable_then_the_default(configs, monkeypatch):
    tmp, paths = configs
    assert socket_path(_args()) == ControlConfig().socket
    monkeypatch.setenv("NURBSMOTION_CONFIG", str(paths["a"]))
    assert socket_path(_args()) == str(tmp / "a.sock")
    monkeypatch.setenv("NURBSMOTION_SOCKET", str(tmp / "env.sock"))
    assert socket_path(_args()) == str(tmp / "env.sock")
    assert socket_path(_args(config=str(paths["b"]))) == str(tmp / "b.sock")
    assert socket_path(_args(socket="/x/y.sock")) == "/x/y.sock"


def test_a_client_uses_the_environment_and_says_where_it_looked(configs, monkeypatch, capsys):
    tmp, paths = configs
    monkeypatch.setenv("NURBSMOTION_CONFIG", str(paths["b"]))
    assert main(["status"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"nurbsmotion status: error: no daemon at {tmp / 'b.sock'} (is it running?)"]


def test_a_bad_config_variable_is_one_line_naming_the_file(configs, monkeypatch, capsys):
    tmp, _ = configs
    monkeypatch.setenv("NURBSMOTION_CONFIG", str(tmp / "missing.yaml"))
    assert main(["status"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.yaml" in err[0]


def test_the_daemon_takes_its_config_from_the_variable_or_says_it_needs_one(configs, monkeypatch, capsys):
    assert main(["daemon"]) == 2
    assert "NURBSMOTION_CONFIG" in capsys.readouterr().err


def test_jobs_reads_the_records_itself_when_no_daemon_answers(configs, monkeypatch, capsys):
    from nurbsmotion.service.records import JobRecords

    tmp, paths = configs
    paths["a"].write_text(paths["a"].read_text() + f"data_dir: {tmp / 'data'}\n")
    record = JobRecords(tmp / "data").create_rejected("bad.nc", "G01 Q7\n", ["bad.nc:1: Q7: unsupported word Q"])
    monkeypatch.setenv("NURBSMOTION_CONFIG", str(paths["a"]))
    assert main(["jobs"]) == 0
    out = capsys.readouterr()
    assert f"read from {tmp / 'data' / 'jobs'}" in out.err and record.job_id in out.out and "rejected" in out.out
    assert main(["jobs", record.job_id]) == 0
    assert "error       bad.nc:1: Q7: unsupported word Q" in capsys.readouterr().out
    assert main(["jobs", "--socket", str(tmp / "none.sock")]) == 3  # an explicit socket: no guessing
    assert "no daemon at" in capsys.readouterr().err
