"""Short-segment smoothing in the look-ahead (planning/lookahead/smoothing.py): runs of short
G01 lines merged and fitted within the path tolerance. The rulers: planning.path_deviation
(every set-point against the program's own blocks) and planning.measure against the planned
pieces (conftest.measure_planned)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.errors import InputError
from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning import path_deviation as pd
from nurbsmotion.planning.lookahead import plan_lookahead, plan_lookahead_chunks, planned_pieces
from nurbsmotion.planning.lookahead.smoothing import MERGE_SHARE, merged_vertices
from nurbsmotion.program import Program, parse_gcode
from nurbsmotion.program.model import with_feeds_capped
from tests.planning.lookahead.conftest import assert_within_limits, measure_planned, polyline
from tests.planning.lookahead.test_no_give_ups import braid_program

DATA = Path(__file__).resolve().parents[2] / "data" / "gcode"
LIMITS = PlanLimits(period_s=0.001, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0, default_feed_mm_s=200.0,
                    rapid_feed_mm_s=200.0, path_tolerance_mm=0.01, junction_deviation_mm=0.01, smoothing=True)
NO_JERK = replace(LIMITS, max_jerk_mm_s3=None)


def capped(program: Program, feed_mm_s: float = 200.0) -> Program:
    return with_feeds_capped(program, feed_mm_s)


def vcarve(lines: int | None = None) -> Program:
    """CAMotics' vcarve.ngc (micrometre segments that move Z too), G20 and F6 on two lines as
    benchmarks/bench_vs_linuxcnc.vcarve_fix reads it, its G64 P0.001 (inch) at 0.01 mm as in
    the race; its first ``lines`` lines."""
    text = (DATA / "camotics_vcarve.ngc").read_text().replace("G20 F6", "G20\nF6", 1)
    text = text.replace("G64 P0.001", f"G64 P{0.01 / 25.4:.9f}", 1).splitlines()
    text = text[:lines] + ["M2"] if lines else text
    return parse_gcode("\n".join(text) + "\n", "camotics_vcarve.ngc")


def deviation_mm(trajectory, program: Program) -> float:
    return float(pd.distances_to_path(trajectory.position_mm, pd.program_path(program)).max())


def circle_chords(n: int, radius: float = 5.0, noise_mm: float = 0.0) -> list[tuple[float, float, float]]:
    angle = np.linspace(0.0, 1.5 * np.pi, n + 1)
    rng = np.random.default_rng(7)
    r = radius + noise_mm * rng.uniform(-1.0, 1.0, n + 1)
    return [(float(x), float(y), 0.0) for x, y in zip(r * np.cos(angle), r * np.sin(angle))]


@pytest.mark.parametrize("name", ["grbl_HSM_test.nc", "braid_cut2d.nc", "camotics_vcarve.ngc"])
def test_real_cam_programs_stay_within_the_tolerance_and_every_limit(name):
    program = {"braid_cut2d.nc": braid_program, "camotics_vcarve.ngc": vcarve}.get(
        name, lambda: parse_gcode((DATA / name).read_text(), name))()
    program = capped(program)
    pieces = planned_pieces(program, LIMITS)
    assert sum(p.covered is not None for p in pieces) > 0  # something was smoothed
    trajectory = plan_lookahead(program, LIMITS)
    deviation = deviation_mm(trajectory, program)
    assert deviation <= LIMITS.path_tolerance_mm
    assert trajectory.notes["verified_max_path_deviation_mm"] == pytest.approx(deviation, abs=1e-7)  # the planner's own
    assert_within_limits(measure_planned(trajectory, program, LIMITS), LIMITS)
    assert np.all(np.diff(trajectory.block) >= 0)  # the line reached never goes back


def test_the_vcarve_is_no_longer_a_crawl_with_the_jerk_limit():
    """The V-carve regression (docs/lookahead.md, section 3): blends and junctions on its
    micrometre segments are passed at a crawl, and with J each such dip costs about A/J; the
    merge removes them (the segments' noise is far inside the tolerance)."""
    program = capped(vcarve(700))
    smoothed = plan_lookahead(program, LIMITS)
    plain = plan_lookahead(program, replace(LIMITS, smoothing=False))
    assert len(smoothed) < 0.5 * len(plain)
    assert smoothed.notes["runs"] < plain.notes["runs"]
    assert deviation_mm(smoothed, program) <= LIMITS.path_tolerance_mm


def test_merged_vertices_keep_every_dropped_vertex_within_the_tolerance():
    rng = np.random.default_rng(3)
    s = np.cumsum(rng.uniform(0.0, 0.002, 400))
    q = np.stack([s, 0.003 * rng.uniform(-1, 1, 400), np.zeros(400)], axis=1)
    kept = merged_vertices(q, 0.004)
    assert kept[0] == 0 and kept[-1] == len(q) - 1 and len(kept) < len(q) // 10  # noise inside it: few chords
    for a, b in zip(kept[:-1], kept[1:]):
        d = q[b] - q[a]
        t = np.clip((q[a + 1:b] - q[a]) @ d / (d @ d), 0.0, 1.0)
        assert np.all(np.linalg.norm(q[a + 1:b] - q[a] - t[:, None] * d, axis=1) <= 0.004)


@pytest.mark.parametrize("limits", [LIMITS, NO_JERK], ids=["jerk", "no-jerk"])
def test_a_circle_of_chords_becomes_a_curve_within_the_tolerance(limits):
    program = polyline(circle_chords(300, noise_mm=0.002), feed_mm_s=100.0)
    pieces = planned_pieces(program, limits)
    assert any(p.covered is not None and p.curve.degree == 3 for p in pieces)
    trajectory = plan_lookahead(program, limits)
    assert trajectory.notes["stops"] == 0
    assert deviation_mm(trajectory, program) <= limits.path_tolerance_mm
    assert_within_limits(measure_planned(trajectory, program, limits), limits)


def test_the_line_reached_is_the_segment_the_set_point_is_on():
    points = circle_chords(300)
    program = polyline(points, feed_mm_s=100.0)
    trajectory = plan_lookahead(program, LIMITS)
    assert np.all(np.diff(trajectory.block) >= 0)
    a, b = np.array(points[:-1]), np.array(points[1:])
    for p, block in zip(trajectory.position_mm[::25], trajectory.block[::25]):
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
        nearest = int(np.argmin(np.linalg.norm(p - a - t[:, None] * ab, axis=1)))
        assert abs(int(block) - nearest) <= 1


def test_q0_and_smoothing_false_plan_the_program_as_without_smoothing():
    chords = circle_chords(120)
    body = "".join(f"G1 X{x:.4f} Y{y:.4f}\n" for x, y, _ in chords[1:])
    start = f"G21 G90\nG0 X{chords[0][0]:.4f} Y{chords[0][1]:.4f}\nF6000\n"
    off = plan_lookahead(parse_gcode(start + "G64 P0.01\n" + body, "t.nc"), replace(LIMITS, smoothing=False))
    q0 = plan_lookahead(parse_gcode(start + "G64 P0.01 Q0\n" + body, "t.nc"), LIMITS)
    on = parse_gcode(start + "G64 P0.01\n" + body, "t.nc")
    np.testing.assert_array_equal(off.position_mm, q0.position_mm)
    np.testing.assert_array_equal(off.block, q0.block)
    assert not any(p.covered is not None for p in planned_pieces(on, replace(LIMITS, smoothing=False)))
    assert any(p.covered is not None for p in planned_pieces(on, LIMITS))


def test_exact_stops_and_sharp_corners_stay():
    """A 90 deg corner of 1 mm segments and a G61 block inside a run of short lines: the
    set-points pass through both vertices at rest."""
    chords = [(0.1 * i, 0.0) for i in range(31)] + [(3.0, 1.0)] + [(3.0 + 0.1 * i, 1.0) for i in range(1, 31)]
    lines = ["G21 G90", "G0 X0 Y0", "F6000"] + [f"G1 X{x:.4f} Y{y:.4f}" for x, y in chords[1:]]
    lines[3 + 45] = "G61 " + lines[3 + 45]
    lines.insert(3 + 46, "G64 P0.01")
    program = parse_gcode("\n".join(lines) + "\n", "t.nc")
    trajectory = plan_lookahead(program, LIMITS)
    for corner in [(3.0, 0.0, 0.0), (3.0, 1.0, 0.0), program.blocks[45].curve.end_point[:3]]:
        at = np.flatnonzero(np.all(np.abs(trajectory.position_mm - corner) < 1e-12, axis=1))
        assert len(at) >= 2  # reached, and held one cycle (a stop)
    assert deviation_mm(trajectory, program) <= LIMITS.path_tolerance_mm


def test_chunks_plan_the_same_pieces_as_the_whole_plan():
    program = polyline(circle_chords(600, radius=40.0, noise_mm=0.002), feed_mm_s=100.0)
    whole = plan_lookahead(program, LIMITS)
    chunks = list(plan_lookahead_chunks(program, LIMITS, chunk_cycles=300))
    positions = np.concatenate([c.position_mm for c in chunks])
    assert len(chunks) > 2
    assert abs(len(positions) - len(whole)) <= 0.01 * len(whole)
    assert deviation_mm(replace(whole, position_mm=positions), program) <= LIMITS.path_tolerance_mm


def test_the_smoothing_switch_is_a_bool():
    with pytest.raises(InputError, match="smoothing"):
        PlanLimits(smoothing="yes")  # type: ignore[arg-type]


def test_merge_share_leaves_the_blends_the_rest_of_the_tolerance():
    program = capped(vcarve(700))
    merged = [p for p in planned_pieces(program, LIMITS) if p.covered is not None and p.curve.degree == 1]
    assert merged and all(p.deviation_mm == pytest.approx(MERGE_SHARE * LIMITS.path_tolerance_mm) for p in merged)


def test_the_trace_names_the_block_the_plan_reports():
    from nurbsmotion.planning.lookahead.planned_path import PlannedPath
    from nurbsmotion.planning.measure import MeasureStream
    program = polyline(circle_chords(300, noise_mm=0.002), feed_mm_s=100.0)
    trajectory = plan_lookahead(program, LIMITS)
    path = PlannedPath.of(program, LIMITS)
    stream = MeasureStream(path.program)
    figures = [f for f in (stream.add(path.rows(trajectory)), stream.finish()) if f is not None]
    blocks = np.concatenate([path.on_program(f).rows.block for f in figures])
    np.testing.assert_array_equal(blocks, trajectory.block[:len(blocks)])


def test_resumed_streamed_and_re_planned_plans_run_on_the_smoothed_path():
    from nurbsmotion.planning.lookahead import PlanState, PlanStream, plan_from_state, plan_lookahead_resumable
    program = polyline(circle_chords(600, radius=40.0, noise_mm=0.002), feed_mm_s=100.0)
    end = program.blocks[-1].curve.end_point[:3]
    whole = plan_lookahead(program, LIMITS)
    streamed = np.concatenate([c.position_mm for c in PlanStream(program, LIMITS, chunk_cycles=300)])
    assert abs(len(streamed) - len(whole)) <= 0.01 * len(whole)
    chunks = plan_lookahead_resumable(program, LIMITS, chunk_cycles=300)
    done = [next(chunks), next(chunks)]
    resumed = [c for c, _ in plan_lookahead_resumable(program, replace(LIMITS, feed_mm_s=60.0), 300, done[-1][1])]
    replanned = list(plan_from_state(program, LIMITS, PlanState(50.0, 80.0, 0.0)))
    for part in (streamed, np.concatenate([c.position_mm for c, _ in done] + [c.position_mm for c in resumed]),
                 np.concatenate([c.position_mm for c in replanned])):
        assert float(pd.distances_to_path(part, pd.program_path(program)).max()) <= LIMITS.path_tolerance_mm
        np.testing.assert_array_equal(part[-1], end)
    assert all(np.all(np.diff(c.block) >= 0) for c in resumed + replanned)


@pytest.mark.parametrize("seed", range(4))
def test_random_short_segment_paths_hold_the_tolerance_and_every_limit(seed):
    """Random walks of 0.001-0.5 mm segments turning by up to 40 deg, in 3-D, with noise at
    the tolerance's scale: whatever is merged, fitted or blended stays within it."""
    rng = np.random.default_rng(seed)
    n = 250
    turn = np.cumsum(rng.normal(0.0, np.radians(rng.uniform(1, 40)), n))
    step = rng.uniform(0.001, 0.5, n) * (rng.random(n) < 0.8) + 0.001
    xyz = np.cumsum(np.stack([step * np.cos(turn), step * np.sin(turn), 0.05 * step * rng.normal(size=n)], axis=1), axis=0)
    xyz += rng.uniform(-0.003, 0.003, xyz.shape)
    program = polyline([(0.0, 0.0, 0.0)] + [tuple(p) for p in xyz], feed_mm_s=float(rng.uniform(20, 200)))
    limits = LIMITS if seed % 2 else NO_JERK
    trajectory = plan_lookahead(program, limits)
    assert deviation_mm(trajectory, program) <= limits.path_tolerance_mm
    assert_within_limits(measure_planned(trajectory, program, limits), limits)
    assert np.all(np.diff(trajectory.block) >= 0)


def test_a_feed_override_resumes_on_the_same_pieces():
    """Chains end where the programmed F changes, whatever the override: a resumed plan with
    a new feed continues on the piece the old plan stopped on."""
    chords = circle_chords(600, radius=40.0, noise_mm=0.002)
    lines = ["G21 G90", f"G0 X{chords[0][0]:.4f} Y{chords[0][1]:.4f}"]
    lines += [f"G1 X{x:.4f} Y{y:.4f} F{6000 if i < 300 else 3000}" for i, (x, y, _) in enumerate(chords[1:])]
    program = parse_gcode("\n".join(lines) + "\n", "t.nc")
    from nurbsmotion.planning.lookahead import plan_lookahead_resumable
    slow = replace(LIMITS, feed_mm_s=40.0)
    assert [p.covered is not None for p in planned_pieces(program, LIMITS)] == \
        [p.covered is not None for p in planned_pieces(program, slow)]
    chunks = plan_lookahead_resumable(program, LIMITS, chunk_cycles=300)
    done = [next(chunks) for _ in range(2)]  # the rapid, then a chunk that ends moving
    resumed = next(iter(plan_lookahead_resumable(program, slow, 300, done[-1][1])))[0]
    step = np.linalg.norm(resumed.position_mm[0] - done[-1][0].position_mm[-1])
    assert step <= 1.01 * 100.0 * LIMITS.period_s  # the next set-point, one cycle on (F6000 = 100 mm/s)
