#!/usr/bin/python3
"""Headless DISPLAY program for the LinuxCNC race (bench_vs_linuxcnc.py): runs one program
and exits, which makes the ``linuxcnc`` script shut everything down.

LinuxCNC starts it as ``linuxcnc_display.py -ini FILE``; it reads [RACE] PROGRAM, SAMPLES,
STATUS and TIMEOUT_S from that INI. It records the servo thread's samples with
``halsampler -t`` into SAMPLES while the program runs, and writes a JSON status
({"ok": bool, "errors": [...], "wall_s": float}) to STATUS. Runs under Debian's
/usr/bin/python3 (the ``linuxcnc`` module is built for it), not the project's venv.
"""

import json
import subprocess
import sys
import time

import linuxcnc  # type: ignore[import-not-found]

SETTLE_S = 0.3  # samples kept after the program ends (the last moving sample is before them)
POLL_S = 0.02
START_S = 60.0  # the interpreter leaves its idle state this soon after AUTO_RUN (a loaded host is slow)
IDLE_S = 0.5  # the interpreter idle and the motion queue empty this long: the program has ended


def ini_value(ini, name):
    value = ini.find("RACE", name)
    if value is None:
        raise SystemExit(f"linuxcnc_display: [RACE] {name} missing from the INI")
    return value


def wait_until(predicate, stat, timeout_s):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        stat.poll()
        if predicate(stat):
            return True
        time.sleep(POLL_S)
    return False


def drain_errors(channel, errors):
    while True:
        message = channel.poll()
        if not message:
            return
        kind, text = message
        if kind in (linuxcnc.NML_ERROR, linuxcnc.OPERATOR_ERROR):
            errors.append(text.strip())


def run(ini_path):
    ini = linuxcnc.ini(ini_path)
    program, samples, status_path = ini_value(ini, "PROGRAM"), ini_value(ini, "SAMPLES"), ini_value(ini, "STATUS")
    timeout_s = float(ini_value(ini, "TIMEOUT_S"))
    errors = []
    started = time.monotonic()
    with open(samples, "w") as out:
        sampler = subprocess.Popen(["halsampler", "-t"], stdout=out)
        try:
            ok = drive(program, timeout_s, errors)
            time.sleep(SETTLE_S)
        finally:
            sampler.terminate()
            sampler.wait(5)
    stat = linuxcnc.stat()
    stat.poll()
    with open(status_path, "w") as f:  # the lines reached: a run that ended early shows it here
        json.dump({"ok": ok and not errors, "errors": errors, "wall_s": time.monotonic() - started,
                   "motion_line": stat.motion_line, "current_line": stat.current_line, "read_line": stat.read_line}, f)


def drive(program, timeout_s, errors):
    command, stat, channel = linuxcnc.command(), linuxcnc.stat(), linuxcnc.error_channel()
    command.state(linuxcnc.STATE_ESTOP_RESET)
    command.wait_complete()
    command.state(linuxcnc.STATE_ON)
    command.wait_complete()
    if not wait_until(lambda s: s.task_state == linuxcnc.STATE_ON, stat, 10.0):
        errors.append("machine did not turn on")
        return False
    command.mode(linuxcnc.MODE_AUTO)
    command.wait_complete()
    command.program_open(program)
    command.wait_complete()
    drain_errors(channel, errors)
    command.auto(linuxcnc.AUTO_RUN, 0)
    if not wait_until(lambda s: s.interp_state != linuxcnc.INTERP_IDLE or s.queue > 0, stat, START_S):
        drain_errors(channel, errors)
        errors.append(f"program did not start within {START_S:g} s")
        return False

    idle_since = [None]

    def finished(s):
        drain_errors(channel, errors)
        paused = s.task_paused or s.interp_state == linuxcnc.INTERP_PAUSED
        if paused:
            errors.append("program paused (M0/M1 or a tool change waiting): not raced")
        idle = s.interp_state == linuxcnc.INTERP_IDLE and s.queue == 0 and s.exec_state == linuxcnc.EXEC_DONE
        if not idle:
            idle_since[0] = None
        elif idle_since[0] is None:
            idle_since[0] = time.monotonic()
        # idle for IDLE_S on end: a one-poll idle state between two reads is not the end
        return bool(errors) or paused or (idle_since[0] is not None and time.monotonic() - idle_since[0] >= IDLE_S)

    if not wait_until(finished, stat, timeout_s):
        errors.append(f"still running after {timeout_s:g} s")
        command.abort()
        return False
    drain_errors(channel, errors)
    return not errors


if __name__ == "__main__":
    run(sys.argv[sys.argv.index("-ini") + 1])
