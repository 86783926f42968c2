"""runtime.keep_freed_memory: large numpy temporaries stop costing page faults."""

from __future__ import annotations

import platform
import resource

import numpy as np
import pytest

from nurbsmotion.runtime import keep_freed_memory

glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")


def faults_of_temporaries(rounds: int = 50) -> int:
    """Minor page faults while creating and dropping 1 MiB arrays."""
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(rounds):
        a = np.ones(131_072)
        del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


@glibc
def test_freed_memory_is_reused_without_page_faults():
    assert keep_freed_memory() is True
    faults_of_temporaries(2)  # the heap grows once
    assert faults_of_temporaries() == 0


def test_every_command_applies_it(monkeypatch, tmp_path):
    from nurbsmotion import cli

    called = []
    monkeypatch.setattr(cli, "keep_freed_memory", lambda: called.append(True) or True)
    assert cli.main(["status", "--socket", str(tmp_path / "none.sock")]) == 3  # no daemon there
    assert called == [True]
