"""runtime.keep_freed_memory: planning stops paying page faults for its numpy temporaries."""

from __future__ import annotations

import json
import platform
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")

# A fresh process: what glibc does depends on what the process allocated before. The control
# does not count on glibc's own trimming: glibc gives freed heap back only from the top, when
# the free space there exceeds its trim threshold at a large free() (malloc(3)), so whether a
# plan's temporaries go back depends on the heap's layout, left by everything the process did
# before. In a fresh clone's first run (the project's modules compiled from source, not loaded
# from __pycache__) one plan of three started on the heap its predecessor left untrimmed and
# faulted nothing; with every module compiled from source no plan did: the temporaries fit in
# the holes compiling left (docs/reliability.md, flake 15). So the control gives every free
# page of the heap back before each plan (malloc_trim(0): what glibc's trimming does at most),
# and counts what the plan then faults in again: what keep_freed_memory keeps mapped.
PLAN_FAULTS = r"""
import ctypes, ctypes.util, json, resource, sys
sys.path.insert(0, sys.argv[1])
from dataclasses import replace
from benchmarks.bench_lookahead import WANG_LIMITS, wang_program
from nurbsmotion.planning.lookahead import plan_lookahead
from nurbsmotion.runtime import keep_freed_memory

malloc_trim = ctypes.CDLL(ctypes.util.find_library("c")).malloc_trim

def faults_of_a_plan(give_back):
    limits = replace(WANG_LIMITS, period_s=0.001, max_jerk_mm_s3=50000.0)  # the default planner's set-up
    for _ in range(3):  # warm up: the heap reaches its working size
        plan_lookahead(wang_program(), limits)
    counts = []
    for _ in range(3):  # the least of three: the kernel's own work on a busy host adds faults to one plan
        give_back()
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        plan_lookahead(wang_program(), limits)
        counts.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    return min(counts)

default = faults_of_a_plan(lambda: malloc_trim(0))  # every free page of the heap back to the kernel
kept = keep_freed_memory()
print(json.dumps({"default": default, "kept": kept, "after": faults_of_a_plan(lambda: None)}))
"""


def plan_faults(pycache_prefix: Path | None = None) -> dict[str, int | bool]:
    """The child's counts; with ``pycache_prefix`` (empty) it compiles every module it imports
    from source, as the first run in a fresh clone compiles the project's."""
    env = {"PYTHONPATH": str(ROOT / "src"), "PATH": "/usr/bin:/bin"}
    if pycache_prefix is not None:
        env["PYTHONPYCACHEPREFIX"] = str(pycache_prefix)
    out = subprocess.run([sys.executable, "-c", PLAN_FAULTS, str(ROOT)], capture_output=True, text=True, check=True,
                         env=env)
    return json.loads(out.stdout)


@glibc
@pytest.mark.parametrize("compiled", [False, True], ids=["modules-as-found", "compiled-from-source"])
def test_a_plan_after_keep_freed_memory_causes_no_page_faults(compiled, tmp_path):
    faults = plan_faults(tmp_path / "pycache" if compiled else None)
    assert faults["kept"] is True
    assert faults["after"] <= 10  # the odd page of Python's own objects
    assert faults["default"] > 10 * max(faults["after"], 1)  # a plan on a heap given back faults its temporaries in


def test_the_commands_that_compute_apply_it_and_the_control_clients_do_not(monkeypatch, tmp_path):
    """check, plan, daemon, demo, sim, compare plan in their own process: they keep freed
    memory; a control client (status) starts without it (cli.COMMANDS, issue 25 part 5)."""
    from nurbsmotion import cli, runtime

    called = []
    monkeypatch.setattr(runtime, "keep_freed_memory", lambda: called.append(True) or True)
    assert cli.main(["status", "--socket", str(tmp_path / "none.sock")]) == 3  # no daemon there
    assert called == []
    program = tmp_path / "line.nc"
    program.write_text("G21 G90 G01 X1 F600\n")
    assert cli.main(["check", str(program)]) == 0
    assert called == [True]
