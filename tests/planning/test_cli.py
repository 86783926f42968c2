"""``nurbsmotion plan`` and ``compare`` on the papers' example, in process."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.cli import main
from nurbsmotion.planning.trace import TRACE_COLUMNS, read_trace

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
WANG_NC = str(EXAMPLES / "wang_table1.nc")
WANG_CONFIG = str(EXAMPLES / "wang_experiment.yaml")


def test_plan_summary_trace_and_plot(capsys, tmp_path):
    trace, png = tmp_path / "wang.csv", tmp_path / "wang.png"
    assert main(["plan", WANG_NC, "--config", WANG_CONFIG, "--algorithm", "wang",
                 "--trace", str(trace), "--plot", str(png)]) == 0
    out = capsys.readouterr()
    assert out.err == ""
    assert "max chord error" in out.out and "max resultant accel" in out.out and "planning" in out.out
    data = read_trace(trace)
    assert tuple(data) == TRACE_COLUMNS
    assert data["t"][1] == pytest.approx(0.004)  # the config's 4 ms period
    assert data["chord_error"].max() <= 0.010 and data["accel"].max() <= 2500.0 * (1 + 1e-5)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plan_json_reports_measured_figures_and_cli_overrides(capsys):
    assert main(["plan", WANG_NC, "--config", WANG_CONFIG, "--algorithm", "taylor2", "--period-ms", "2",
                 "--feed-mm-min", "6000", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["algorithm"] == "taylor2"
    assert data["limits"]["period_ms"] == pytest.approx(2.0)
    assert data["measured"]["max_speed_mm_s"] == pytest.approx(100.0, rel=0.02)  # 6000 mm/min overrides F12000
    assert data["measured"]["end_error_mm"] < 1e-9


def test_lookahead_summary_states_every_guarantee_with_its_figure_and_tolerance(capsys):
    assert main(["plan", WANG_NC, "--config", WANG_CONFIG, "--algorithm", "lookahead", "--max-jerk-mm-s3", "50000", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["algorithm"] == "lookahead" and data["tolerance"] == 1e-9
    rows = {r["limit"]: r for r in data["guarantees"]}
    assert {"chord error", "resultant acceleration", "jerk", "feed fluctuation"} <= set(rows)
    for r in rows.values():
        assert 0.0 <= r["verified_max"] <= r["at_most"] * (1 + 1e-9)
    assert rows["jerk"]["at_most"] == 50000.0
    assert main(["plan", WANG_NC, "--config", WANG_CONFIG, "--algorithm", "lookahead"]) == 0
    text = capsys.readouterr().out
    assert "guaranteed on every cycle" in text and "tolerance 1e-09 relative" in text and "verified max" in text


def test_the_papers_methods_claim_no_guarantee(capsys):
    assert main(["plan", WANG_NC, "--config", WANG_CONFIG, "--algorithm", "zhang", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["guarantees"] == []


def test_compare_table_has_a_row_per_algorithm(capsys):
    assert main(["compare", WANG_NC, "--config", WANG_CONFIG, "--algorithms", "taylor2,zhang,lookahead", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    names = [r["algorithm"] for r in data["results"]]
    assert names[:2] == ["taylor2", "zhang"]
    assert "lookahead" in names or "lookahead" in data["skipped"]
    by_name = {r["algorithm"]: r["measured"] for r in data["results"]}
    assert by_name["zhang"]["max_fluctuation"] < by_name["taylor2"]["max_fluctuation"]


def test_compare_text_table(capsys):
    assert main(["compare", WANG_NC, "--algorithms", "taylor1,wang", "--period-ms", "4"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "max chord um" in lines[1] and "max accel mm/s2" in lines[1]
    assert lines[2].split()[0] == "taylor1" and lines[3].split()[0] == "wang"


@pytest.mark.parametrize("argv, where", [
    (["plan", WANG_NC, "--algorithm", "wang", "--period-ms", "-4"], "--period-ms"),
    (["plan", WANG_NC, "--algorithm", "wang", "--period-ms", "250"], "--period-ms"),
    (["plan", WANG_NC, "--algorithm", "nope"], "--algorithm"),
    (["plan", WANG_NC, "--algorithm", "wang", "--chord-error-mm", "abc"], "--chord-error-mm"),
    (["plan", str(EXAMPLES / "missing.nc"), "--algorithm", "wang"], "missing.nc"),
    (["plan", WANG_NC, "--algorithm", "wang", "--config", str(EXAMPLES / "wang_table1.nc")], "wang_table1.nc"),
    (["compare", WANG_NC, "--algorithms", "wang,bogus"], "--algorithms"),
])
def test_bad_options_are_one_line_and_exit_2(capsys, argv, where):
    try:
        code = main(argv)
    except SystemExit as exit_:  # argparse's own checks exit from inside the parser
        code = exit_.code
    assert code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and where in err


def test_plot_without_matplotlib_is_one_line_before_any_work(capsys, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    trace, png = tmp_path / "t.csv", tmp_path / "p.png"
    assert main(["plan", WANG_NC, "--algorithm", "taylor2", "--trace", str(trace), "--plot", str(png)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--plot" in err[0] and "matplotlib" in err[0]
    assert not trace.exists() and not png.exists()


def test_plan_streams_the_same_trace_and_figures_as_a_whole_plan(capsys, tmp_path):
    """--trace is written chunk by chunk (bounded memory); the figures equal a whole-plan
    measure and the trace equals write_trace of the whole trajectory."""
    from nurbsmotion.planning import PlanLimits
    from nurbsmotion.planning.lookahead import plan_lookahead
    from nurbsmotion.planning.measure import measure
    from nurbsmotion.planning.trace import write_trace
    from nurbsmotion.program import read_program

    trace = tmp_path / "streamed.csv"
    assert main(["plan", WANG_NC, "--period-ms", "1", "--max-jerk-mm-s3", "50000", "--trace", str(trace),
                 "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    program = read_program(WANG_NC)
    whole = plan_lookahead(program, PlanLimits(period_s=0.001, max_jerk_mm_s3=50000.0))
    m = measure(whole, program)
    assert data["measured"]["cycles"] == m.cycles
    assert data["measured"]["max_jerk_mm_s3"] == pytest.approx(m.max_jerk_mm_s3, rel=1e-9)
    assert data["measured"]["max_chord_error_mm"] == pytest.approx(m.max_chord_error_mm, rel=1e-12)
    reference = tmp_path / "whole.csv"
    write_trace(reference, whole, m)
    streamed, expected = read_trace(trace), read_trace(reference)
    for column in TRACE_COLUMNS:
        assert np.allclose(streamed[column], expected[column], rtol=1e-6, atol=1e-6), column
    assert not (tmp_path / "streamed.csv.part").exists()


ZIGZAG = "G21 G90 G64 P0.01\nG01 X0 Y0 F6000\n" + "".join(f"G01 X{2 * (i + 1)} Y{(i % 2) * 0.5:.1f}\n" for i in range(40))


@pytest.mark.parametrize("program", ["wang", "zigzag"])
def test_plan_in_a_second_process_reports_and_traces_exactly_what_one_process_does(capsys, tmp_path, monkeypatch,
                                                                                    program):
    """With a core to spare the planner runs in a forked process (cli._forked) while this one
    measures: every figure and every byte of the trace as when one process does both. On a
    blended program (the zigzag) one process measures on the pieces its planner set up
    (PlannedPath.streamed), the forked one sets them up again: the same figures too."""
    import nurbsmotion.cli.plan as plan_command

    path = WANG_NC
    if program == "zigzag":
        path = str(tmp_path / "zigzag.nc")
        Path(path).write_text(ZIGZAG)

    def plan(processes: str) -> tuple[dict, bytes]:
        trace = tmp_path / f"processes{processes}.csv"
        assert main(["plan", path, "--period-ms", "1", "--trace", str(trace), "--json", "--processes", processes]) == 0
        data = json.loads(capsys.readouterr().out)
        data.pop("planning_time_s")
        data.pop("trace")
        return data, trace.read_bytes()

    forked_at: list[bool] = []
    streamed_plan = plan_command.streamed_plan

    def recorded(*args, **kwargs):  # streamed_plan(name, program, limits, chunks_out, forked, stream=)
        forked_at.append(args[4])
        return streamed_plan(*args, **kwargs)

    monkeypatch.setattr(plan_command, "streamed_plan", recorded)
    (forked, forked_trace), (one, one_trace) = plan("2"), plan("1")
    assert forked_at == [True, False]
    assert forked == one
    assert forked_trace == one_trace and len(one_trace) > 100_000
    if program == "zigzag":
        assert one["notes"]["verified_max_path_deviation_mm"] > 0  # blended


def test_a_planning_error_in_the_second_process_is_reported_as_in_one(monkeypatch, tmp_path, capsys):
    """The forked planner's PlanningError reaches the command with its class and place: one
    line on stderr, the JSON error object, exit 2, no trace left behind."""
    from nurbsmotion.planning.lookahead import planner as lookahead_planner

    monkeypatch.setattr(lookahead_planner, "MAX_REPAIR_ROUNDS", 0)  # the child is forked with these
    monkeypatch.setattr(lookahead_planner, "MAX_FEED_HALVINGS", 0)
    reports = []
    for processes in ("2", "1"):
        trace = tmp_path / f"out{processes}.csv"
        assert main(["plan", WANG_NC, "--period-ms", "2", "--max-jerk-mm-s3", "50000", "--trace", str(trace),
                     "--json", "--processes", processes]) == 2
        out = capsys.readouterr()
        assert out.err.count("\n") == 1 and "lookahead cannot hold" in out.err
        assert not trace.exists() and not trace.with_name(trace.name + ".part").exists()
        reports.append((json.loads(out.out), out.err))
    assert reports[0] == reports[1]
    assert reports[0][0]["error"]["where"].startswith(f"{WANG_NC}:")


def test_plan_without_config_plans_with_the_daemons_defaults(capsys):
    """No --config: the interpolation defaults a configuration without that section gets
    (the daemon's), the jerk limit included; --no-jerk-limit removes it."""
    from nurbsmotion.config import InterpolationConfig

    defaults = InterpolationConfig()
    assert main(["plan", WANG_NC, "--algorithm", "taylor2", "--json"]) == 0
    limits = json.loads(capsys.readouterr().out)["limits"]
    assert limits["max_jerk_mm_s3"] == defaults.max_jerk_mm_s3 is not None
    assert (limits["chord_error_mm"], limits["max_accel_mm_s2"], limits["acc_time_s"]) == \
        (defaults.chord_error_mm, defaults.max_accel_mm_s2, defaults.acc_time_s)
    assert main(["plan", WANG_NC, "--algorithm", "taylor2", "--no-jerk-limit", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["limits"]["max_jerk_mm_s3"] is None


def test_a_jerk_limit_and_no_jerk_limit_are_one_line_exit_2(capsys):
    with pytest.raises(SystemExit) as info:
        main(["plan", WANG_NC, "--no-jerk-limit", "--max-jerk-mm-s3", "1000"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--no-jerk-limit" in err[0]


def test_plan_imports_neither_the_fieldbus_nor_matplotlib(tmp_path):
    """``plan`` without --config (the daemon's defaults) reads no drive description: canopen
    and python-can (with asyncio under them) stay out of its start-up, and matplotlib unless
    --plot asks for it."""
    import subprocess

    program = tmp_path / "line.nc"
    program.write_text("G1 X1 F600\nM30\n")
    heavy = ("canopen", "can", "asyncio", "matplotlib", "nurbsmotion.fieldbus", "nurbsmotion.sim")
    script = ("import sys\nfrom nurbsmotion.cli import main\n"
              "main(sys.argv[1:])\n"
              f"print(sorted(m for m in sys.modules if m.split('.')[0] in {heavy!r} or m.startswith({heavy!r})))")
    done = subprocess.run([sys.executable, "-c", script, "plan", str(program), "--json"],
                          capture_output=True, text=True, timeout=60)
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout + done.stderr
