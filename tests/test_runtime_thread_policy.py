"""runtime.realtime_for_normal_threads / normal_again / unpin_threads, in a child process so
that this one's threads are left alone: the demo's threads that are not real-time get the
lowest SCHED_FIFO priority while its in-process drives run (a normal thread holding the
interpreter lock while preempted stalls them all), and none stays pinned to the one CPU every
nurbsmotion process pins its real-time threads to."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

SCRIPT = r"""
import json, os, threading
from nurbsmotion.runtime import normal_again, realtime_for_normal_threads

def policy(tid=0):
    return [os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority]

seen, ready, go = {}, threading.Event(), threading.Event()

def started_later():
    seen["started_later"] = policy()

def worker():
    seen["worker_id"] = threading.get_native_id()
    ready.set()
    go.wait()
    later = threading.Thread(target=started_later)
    later.start()
    later.join()

def realtime_one():
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(5))
    seen["rt_id"] = threading.get_native_id()
    ready.wait()
    go.wait()

w, r = threading.Thread(target=worker), threading.Thread(target=realtime_one)
w.start(); r.start(); ready.wait()
while "rt_id" not in seen:
    pass
raised = realtime_for_normal_threads(1)
seen["main"], seen["worker"], seen["rt"] = policy(), policy(seen["worker_id"]), policy(seen["rt_id"])
go.set(); w.join(); r.join()
normal_again(raised)
seen["main_after"] = policy()
seen["raised"] = sorted(raised)
seen["expected"] = sorted([threading.get_native_id(), seen["worker_id"]])
print(json.dumps(seen))
"""


def test_normal_threads_go_real_time_at_the_priority_and_back_and_real_time_ones_are_left():
    if not hasattr(os, "sched_setscheduler"):
        pytest.skip("no sched_setscheduler on this platform")
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=60)
    if "PermissionError" in done.stderr:
        pytest.skip("SCHED_FIFO not allowed here (no root or CAP_SYS_NICE)")
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout)
    fifo, other = os.SCHED_FIFO, os.SCHED_OTHER
    assert seen["raised"] == seen["expected"]  # this thread and the worker, not the SCHED_FIFO 5 one
    assert seen["main"] == [fifo, 1] and seen["worker"] == [fifo, 1]
    assert seen["rt"] == [fifo, 5]
    assert seen["started_later"] == [fifo, 1]  # a thread started by a raised one inherits it
    assert seen["main_after"] == [other, 0]


UNPIN_SCRIPT = r"""
import json, os, threading
from nurbsmotion.runtime import unpin_threads

cpus = sorted(os.sched_getaffinity(0))
seen, ready, go = {}, threading.Event(), threading.Event()

def pinned():
    os.sched_setaffinity(0, {cpus[-1]})
    seen["id"] = threading.get_native_id()
    ready.set()
    go.wait()

t = threading.Thread(target=pinned)
t.start(); ready.wait()
changed = unpin_threads()
seen["after"] = sorted(os.sched_getaffinity(seen["id"]))
go.set(); t.join()
print(json.dumps({"cpus": cpus, "changed": changed, **seen}))
"""


def test_unpin_threads_gives_a_pinned_thread_every_cpu_of_the_process():
    if not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs two CPUs and sched_setaffinity")
    done = subprocess.run([sys.executable, "-c", UNPIN_SCRIPT], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout)
    assert seen["changed"] == [seen["id"]] and seen["after"] == seen["cpus"]


UNPINNED_REALTIME_SCRIPT = r"""
import json, os, threading
from nurbsmotion.runtime import set_thread_realtime

seen = {"cpus": sorted(os.sched_getaffinity(0))}

def publisher():
    seen["policy"] = set_thread_realtime(1, pin=False)
    seen["sched"] = [os.sched_getscheduler(0), os.sched_getparam(0).sched_priority]
    seen["after"] = sorted(os.sched_getaffinity(0))

t = threading.Thread(target=publisher)
t.start(); t.join()
print(json.dumps(seen))
"""


def test_a_thread_made_real_time_without_pinning_keeps_every_cpu():
    """The daemon's status publisher (service.subscriptions): SCHED_FIFO 1 so that other
    work does not preempt it while it holds the interpreter lock, on any CPU."""
    if not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs two CPUs and sched_setaffinity")
    done = subprocess.run([sys.executable, "-c", UNPINNED_REALTIME_SCRIPT], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout)
    if seen["policy"] != "SCHED_FIFO":
        pytest.skip(f"SCHED_FIFO not allowed here ({seen['policy']})")
    assert seen["sched"] == [os.SCHED_FIFO, 1] and seen["after"] == seen["cpus"]
