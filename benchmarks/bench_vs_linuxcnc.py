"""Race LinuxCNC 2.9's trajectory planner against ours on real CAM programs (issue 24):
same program, same limits; motion time and largest deviation from the programmed path.

Limits (both sides): feed capped at 200 mm/s (LinuxCNC's MAX_LINEAR_VELOCITY; ours: every
block's feed min(F, 200), rapids 200), acceleration 2500 mm/s^2 resultant (LinuxCNC: per
axis 2500 / sqrt 2 = 1767.77, so a diagonal never exceeds 2500), T = 1 ms, path tolerance
G64 P0.01: both sides read the same text, ``with_tolerance`` (linuxcnc_peer.py): a
``G64 P0.01`` line before the program's first line and each of the program's own G64 (with
or without P/Q) replaced by ``G64 P0.01``; G61 left as written. LinuxCNC's Q (naive-CAM
merge) is left at its default (= P). Ours: no jerk limit, and J = 50000 mm/s^3 (the
daemon's default); chord error and junction deviation = the tolerance.

Figures:
- LinuxCNC: its uspace simulation (linuxcnc_peer.py) samples axis X/Y/Z pos-cmd every servo
  period; motion time = periods from the first to the last moving sample, both included;
- ours: ``PlanStream`` chunks of the lookahead planner; motion time = set-points x T;
- deviation: largest distance of every sample / set-point from the programmed path (our
  reader's blocks in machine coordinates: lines, arcs exactly, NURBS sampled to 0.1 um;
  nurbsmotion.planning.path_deviation);
- rs274 check: rs274's STRAIGHT_* and XY ARC_FEED end points against our blocks' end points
  (largest distance, against rs274's 4-decimal resolution).

LinuxCNC runs in real time (a 70 s program takes 70 s): its results are cached in a JSON
keyed by the program text's hash and the limits, so reruns re-measure only our side.

Install LinuxCNC (benchmark only, never a product dependency):
  apt-get update; apt-get install -y --no-install-recommends linuxcnc-uspace
Run: python benchmarks/bench_vs_linuxcnc.py [--quick] [--programs NAME ...] [--src DIR]
     [--linuxcnc-cache FILE] [--markdown FILE] [--docs] [--max-linuxcnc-s S]
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import hashlib
import json
import shlex
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.linuxcnc_peer import (LinuxcncError, RaceLimits, SamplesError, canon_resolution_mm,  # noqa: E402
                                      missing_tools, parse_canon, run_linuxcnc, run_rs274, with_tolerance)

CORPUS = ROOT / "tests" / "data" / "gcode"
DEFAULT_CACHE = ROOT / "benchmarks" / "results" / "linuxcnc_race_cache.json"
HEADLINE = ("grbl_HSM_test.nc", "braid_cut2d.nc", "linuxcnc_nurbs_G5_butterfly-xy.ngc")
JERK_MM_S3 = 50000.0
CHUNK_CYCLES = 20000


# ---- programs ---------------------------------------------------------------------------------------
def braid_fix(text: str) -> str:
    """grbl's braid_cut2d.nc "at F7000" (issue 17/24): its own F7000.0 (line 8), applied from
    its first G1 (line 6, which the file leaves without a feed); line 1 (T1M6) a comment,
    as tests/planning/lookahead/test_no_give_ups.py reads it."""
    lines = text.splitlines()
    if lines[0] == "T1M6" and lines[5] == "G1Z-1.000":
        lines[0], lines[5] = "(T1M6)", "G1Z-1.000F7000"
    return "\n".join(lines) + "\n"


def vcarve_fix(text: str) -> str:
    """CAMotics' vcarve.ngc starts ``G20 F6``: LinuxCNC sets the feed before the units (its
    order of execution; rs274 prints SET_FEED_RATE(6) before USE_LENGTH_UNITS(INCHES), so
    6 mm/min), our reader takes 6 in/min. The two words on two lines (G20, then F6) mean
    6 in/min to both."""
    return text.replace("G20 F6\n", "G20\nF6\n", 1)


FIXES = {"braid_cut2d.nc": braid_fix, "camotics_vcarve.ngc": vcarve_fix}


def source_of(name: str) -> str:
    """The origin prefix of a corpus file (SOURCES.md)."""
    for prefix, origin in (("linuxcnc_", "LinuxCNC"), ("grbl_", "grbl"), ("camotics_", "CAMotics"),
                           ("fusion360_", "Fusion 360"), ("freecad_", "FreeCAD"), ("textbook_", "textbook"),
                           ("braid", "grbl")):
        if name.startswith(prefix):
            return origin
    return "-"


def corpus_names() -> list[str]:
    return sorted(p.name for p in CORPUS.iterdir() if p.suffix in (".nc", ".ngc", ".gcode", ".tap"))


def program_text(name: str) -> tuple[Path, str]:
    """(path, text both sides read): the file, its fix if any, with_tolerance."""
    path = Path(name) if Path(name).exists() else CORPUS / name
    if not path.exists():
        raise SystemExit(f"--programs: {name}: no such file (nor in {CORPUS})")
    text = path.read_text(errors="replace")
    return path, text


# ---- results -----------------------------------------------------------------------------------------
@dataclass
class Side:
    time_s: float | None = None
    max_dev_mm: float | None = None
    skipped: str | None = None


@dataclass
class Row:
    name: str
    source: str
    lines: int
    linuxcnc: Side
    free: Side  # ours, no jerk limit
    jerk: Side  # ours, J = 50000
    rs274_check: str = "-"


# ---- our side -------------------------------------------------------------------------------------------
def import_nurbsmotion(src: str | None) -> dict[str, ModuleType]:
    """The nurbsmotion found first on sys.path (``--src DIR`` first, else this checkout's src)."""
    sys.path.insert(0, src or str(ROOT / "src"))
    import importlib

    names = ("nurbsmotion.program", "nurbsmotion.program.model", "nurbsmotion.planning", "nurbsmotion.planning.lookahead",
             "nurbsmotion.planning.path_deviation", "nurbsmotion.errors")
    return {name.rsplit(".", 1)[-1]: importlib.import_module(name) for name in names}


def capped(program: Any, cap_mm_s: float, modules: dict[str, ModuleType]) -> Any:
    """The program with every block's programmed feed at most the cap (MAX_LINEAR_VELOCITY)."""
    model = modules.get("model")
    if model is not None and hasattr(model, "with_feeds_capped"):
        return model.with_feeds_capped(program, cap_mm_s)
    blocks = tuple(dataclasses.replace(b, feed_mm_s=min(b.feed_mm_s, cap_mm_s)) if b.feed_mm_s is not None
                   and b.feed_mm_s > cap_mm_s else b for b in program.blocks)  # an older tree's dataclass Blocks
    return dataclasses.replace(program, blocks=blocks)


def our_limits(race: RaceLimits, jerk: float | None, modules: dict[str, ModuleType]) -> Any:
    return modules["planning"].PlanLimits(period_s=race.period_s, chord_error_mm=race.tolerance_mm,
                                          max_accel_mm_s2=race.accel_mm_s2, max_jerk_mm_s3=jerk,
                                          default_feed_mm_s=race.feed_cap_mm_s, rapid_feed_mm_s=race.feed_cap_mm_s,
                                          junction_deviation_mm=race.tolerance_mm)


def plan_ours(program: Any, path: Any, race: RaceLimits, jerk: float | None, modules: dict[str, ModuleType]) -> Side:
    """Motion time (set-points x T) and the largest distance of any set-point from the path."""
    limits = our_limits(race, jerk, modules)
    count, worst = 0, 0.0
    try:
        for chunk in modules["lookahead"].PlanStream(program, limits, CHUNK_CYCLES):
            trajectory = chunk[0] if isinstance(chunk, tuple) else chunk
            count += len(trajectory)
            d = modules["path_deviation"].distances_to_path(trajectory.position_mm, path)
            worst = max(worst, float(d.max()) if len(d) else 0.0)
    except Exception as err:  # noqa: BLE001 - a benchmark reports a failed plan as a row
        return Side(skipped=f"ours: {type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}")
    return Side(count * race.period_s, worst)


@dataclass
class OursCache:
    """Our results keyed by program text, limits, J and a hash of the measured nurbsmotion's
    sources: a rerun of the same code re-uses them (e.g. to write the docs after a long
    run), any change to the planner (or --src) measures again."""

    path: Path | None
    src_hash: str
    entries: dict[str, Any]

    @classmethod
    def open(cls, path: Path | None, package_dir: Path) -> OursCache:
        digest = hashlib.sha256()
        for file in sorted(package_dir.rglob("*.py")):
            digest.update(str(file.relative_to(package_dir)).encode() + b"\0" + file.read_bytes())
        return cls(path, digest.hexdigest()[:16], load_cache(path) if path else {})

    def side(self, text: str, race: RaceLimits, jerk: float | None, measure: Any, cached_only: bool = False) -> Side:
        key = f"{cache_key(text, race)}/J{jerk}/src{self.src_hash}"
        if key not in self.entries and cached_only:
            return Side(skipped="ours: not measured (not in the cache, --from-caches)")
        if key not in self.entries:
            self.entries[key] = dataclasses.asdict(measure())
            if self.path:
                save_cache(self.path, self.entries)
        return Side(**self.entries[key])


def read_ours(text: str, name: str, modules: dict[str, ModuleType]) -> tuple[Any, str | None]:
    """Our reader's program, or the first line of its refusal."""
    try:
        return modules["program"].parse_gcode(text, name), None
    except Exception as err:  # noqa: BLE001 - InputError(s) and anything else: reported, not raised
        return None, f"ours: {str(err).splitlines()[0]}"


# ---- rs274 -------------------------------------------------------------------------------------------------
def rs274_check(program_file: Path, program: Any, home: Path) -> tuple[str | None, str]:
    """(rs274's refusal or None, cross-check text): its move end points against our blocks'."""
    from scipy.spatial import cKDTree

    canon, error = run_rs274(program_file, home)
    if error is not None:
        return f"rs274: {error}", "-"
    try:
        ends = np.array([m.end_mm for m in parse_canon(canon)]).reshape(-1, 3)
    except ValueError as err:
        return None, f"rs274 output not understood ({err})"
    ours = np.vstack([program.start_position[None, :]] + [b.end[None, :] for b in program.blocks])
    if not len(ends):
        return None, "no moves"
    far = float(cKDTree(ours).query(ends)[0].max())
    resolution = canon_resolution_mm(canon)
    verdict = "ok" if far <= resolution + 1e-9 else "DIFFERS"
    return None, f"{verdict}: {len(ends)} end points, max {far:.2g} mm (resolution {resolution:.2g})"


# ---- LinuxCNC side, cached -------------------------------------------------------------------------------------
def cache_key(text: str, race: RaceLimits) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16] + "/" + race.key()


def load_cache(path: Path) -> dict[str, Any]:
    if not path.exists():
        return {}
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError) as err:
        raise SystemExit(f"--linuxcnc-cache {path}: not a JSON cache ({err})") from None


def save_cache(path: Path, cache: dict[str, Any]) -> None:
    """Merge into what is on disk (another run may have added entries), written atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    merged = {**load_cache(path), **cache}
    cache.update(merged)
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(merged, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)


def run_peer(text: str, name: str, path: Any, race: RaceLimits, timeout_s: float, last_move_line: int,
             modules: dict[str, ModuleType]) -> dict[str, Any]:
    """One LinuxCNC run: motion time and largest deviation of its samples from our path."""
    with tempfile.TemporaryDirectory(prefix="race-") as tmp:
        os.chmod(tmp, 0o755)
        started = time.monotonic()
        try:
            samples = run_linuxcnc(text, race, Path(tmp) / "run", timeout_s, last_move_line)
        except (LinuxcncError, SamplesError, subprocess.TimeoutExpired) as err:
            return {"skipped": f"LinuxCNC: {str(err).splitlines()[0]}", "program": name}
        wall = time.monotonic() - started
    moving = samples.moving_positions()
    d = modules["path_deviation"].distances_to_path(moving, path)
    return {"program": name, "motion_cycles": samples.motion_cycles(), "time_s": samples.motion_cycles() * race.period_s,
            "max_dev_mm": float(d.max()) if len(d) else 0.0, "samples": len(samples.position_mm),
            "wall_s": round(wall, 1), "measured": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}


# ---- table ----------------------------------------------------------------------------------------------------
def fmt_time(side: Side) -> str:
    return f"{side.time_s:.2f} s" if side.time_s is not None else "-"


def fmt_dev(side: Side) -> str:
    return f"{side.max_dev_mm:.4f}" if side.max_dev_mm is not None else "-"


def fmt_ratio(ours: Side, peer: Side) -> str:
    if ours.time_s is None or peer.time_s is None or peer.time_s <= 0:
        return "-"
    return f"{ours.time_s / peer.time_s:.2f}x"


def table(rows: list[Row]) -> str:
    out = ["| program | source | lines | LinuxCNC time | LinuxCNC max dev mm | ours no-J time | dev mm | ratio "
           "| ours J=50000 time | dev mm | ratio |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    skipped = []
    for r in rows:
        reason = r.linuxcnc.skipped or r.free.skipped
        if reason and r.linuxcnc.time_s is None and r.free.time_s is None:
            skipped.append(f"- {r.name}: {reason}")
            continue
        out.append(f"| {r.name} | {r.source} | {r.lines} | {fmt_time(r.linuxcnc)} | {fmt_dev(r.linuxcnc)} "
                   f"| {fmt_time(r.free)} | {fmt_dev(r.free)} | {fmt_ratio(r.free, r.linuxcnc)} "
                   f"| {fmt_time(r.jerk)} | {fmt_dev(r.jerk)} | {fmt_ratio(r.jerk, r.linuxcnc)} |")
        for side, label in ((r.linuxcnc, "LinuxCNC"), (r.free, "ours no-J"), (r.jerk, "ours J")):
            if side.skipped and side.time_s is None:
                skipped.append(f"- {r.name} ({label}): {side.skipped}")
    checks = [f"- {r.name}: {r.rs274_check}" for r in rows if r.rs274_check != "-"]
    text = "\n".join(out)
    if checks:
        text += "\n\nEnd points against `rs274 -g` (its STRAIGHT_* and XY ARC_FEED ends vs our blocks' ends):\n" + "\n".join(checks)
    if skipped:
        text += "\n\nNot raced:\n" + "\n".join(skipped)
    return text


# ---- main ------------------------------------------------------------------------------------------------------
def race_one(name: str, race: RaceLimits, cache: dict[str, Any], cache_path: Path, ours: OursCache,
             modules: dict[str, ModuleType],
             max_linuxcnc_s: float, linuxcnc_ok: bool, with_jerk: bool, from_caches: bool = False) -> Row:
    file, raw = program_text(name)
    fixed = FIXES.get(file.name, lambda t: t)(raw)
    text = with_tolerance(fixed, race.tolerance_mm)
    row = Row(file.name, source_of(file.name), len(raw.splitlines()), Side(), Side(), Side())
    program, refusal = read_ours(text, file.name, modules)
    if refusal is not None:
        row.linuxcnc = row.free = row.jerk = Side(skipped=refusal)
        return row
    program = capped(program, race.feed_cap_mm_s, modules)
    path = modules["path_deviation"].program_path(program)
    with tempfile.TemporaryDirectory(prefix="race-rs274-") as tmp:
        copy = Path(tmp) / file.name
        copy.write_text(text)
        refusal, row.rs274_check = (rs274_check(copy, program, Path(tmp) / "home") if shutil.which("rs274")
                                    else (None, "-"))
    row.free = ours.side(text, race, None, lambda: plan_ours(program, path, race, None, modules), from_caches)
    print(f"  {file.name}: ours no-J {fmt_time(row.free)} dev {fmt_dev(row.free)}", file=sys.stderr, flush=True)
    if refusal is not None:
        row.linuxcnc = Side(skipped=refusal)
    else:
        last_line = max((b.source.line for b in program.blocks), default=0)
        row.linuxcnc = peer_side(text, file.name, path, row.free, race, cache, cache_path, modules, max_linuxcnc_s,
                                 linuxcnc_ok, last_line)
    if with_jerk and row.linuxcnc.time_s is not None:
        row.jerk = ours.side(text, race, JERK_MM_S3, lambda: plan_ours(program, path, race, JERK_MM_S3, modules),
                             from_caches)
    print(f"  {file.name}: LinuxCNC {fmt_time(row.linuxcnc)} {row.linuxcnc.skipped or ''}; ours J {fmt_time(row.jerk)}",
          file=sys.stderr, flush=True)
    return row


def peer_side(text: str, name: str, path: Any, free: Side, race: RaceLimits, cache: dict[str, Any], cache_path: Path,
              modules: dict[str, ModuleType], max_linuxcnc_s: float, linuxcnc_ok: bool, last_move_line: int) -> Side:
    key = cache_key(text, race)
    entry = cache.get(key)
    if entry is None:
        if not linuxcnc_ok:
            return Side(skipped="LinuxCNC: not in the cache (not run)")
        estimate = free.time_s or 0.0
        if estimate > max_linuxcnc_s:
            return Side(skipped=f"LinuxCNC not run: ours takes {estimate:.0f} s > --max-linuxcnc-s {max_linuxcnc_s:g}")
        entry = run_peer(text, name, path, race, 3.0 * estimate + 120.0, last_move_line, modules)
        cache[key] = entry
        save_cache(cache_path, cache)
    if "skipped" in entry:
        return Side(skipped=entry["skipped"])
    return Side(entry["time_s"], entry["max_dev_mm"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--programs", nargs="+", metavar="NAME", help="corpus file names or paths (default: the corpus)")
    parser.add_argument("--quick", action="store_true", help="the three headline programs: " + ", ".join(HEADLINE))
    parser.add_argument("--src", metavar="DIR", help="src/ of the nurbsmotion checkout to measure (default: this one's)")
    parser.add_argument("--linuxcnc-cache", type=Path, default=DEFAULT_CACHE, metavar="FILE")
    parser.add_argument("--ours-cache", type=Path, default=Path(tempfile.gettempdir()) / "nurbsmotion_race_ours.json",
                        metavar="FILE", help="our results, keyed by the measured sources' hash too ('' to plan again)")
    parser.add_argument("--markdown", type=Path, metavar="FILE", help="also write the table to FILE")
    parser.add_argument("--docs", action="store_true", help="write the section 'Race against LinuxCNC' of docs/benchmarks.md")
    parser.add_argument("--max-linuxcnc-s", type=float, default=300.0, metavar="S",
                        help="do not run LinuxCNC on programs ours takes longer than S to run (real time)")
    parser.add_argument("--cache-only", action="store_true", help="never run LinuxCNC: cached results only")
    parser.add_argument("--from-caches", action="store_true",
                        help="plan nothing and run nothing: both sides from the caches (writing the docs after long runs)")
    parser.add_argument("--no-jerk", action="store_true",
                        help="skip ours with J (e.g. to fill the LinuxCNC cache while another run plans)")
    args = parser.parse_args()
    if args.src and not (Path(args.src) / "nurbsmotion").is_dir():
        raise SystemExit(f"--src {args.src}: no nurbsmotion package there")
    missing = missing_tools()
    if missing and not (args.cache_only or args.from_caches):
        raise SystemExit(missing)
    modules = import_nurbsmotion(args.src)
    if args.ours_cache is not None and str(args.ours_cache) in ("", "."):
        args.ours_cache = None
    names = list(HEADLINE) if args.quick else (args.programs or corpus_names())
    race = RaceLimits()
    cache = load_cache(args.linuxcnc_cache)
    os.nice(10)  # our side; LinuxCNC's processes get their priority back (run_linuxcnc, as root)
    ours = OursCache.open(args.ours_cache, Path(modules["program"].__file__).resolve().parents[1])
    rows: list[Row] = []
    for name in names:
        rows.append(race_one(name, race, cache, args.linuxcnc_cache, ours, modules, args.max_linuxcnc_s,
                             missing is None and not (args.cache_only or args.from_caches), not args.no_jerk,
                             args.from_caches))
        if args.markdown:  # after every program: a long run's rows so far
            args.markdown.write_text(table(rows) + "\n")
    body = table(rows)
    sys.stdout.write(body + "\n")
    if args.docs:
        write_docs(body, args)


def write_docs(body: str, args: argparse.Namespace) -> None:
    from benchmarks._report import write_section

    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    command = "python benchmarks/bench_vs_linuxcnc.py " + shlex.join(sys.argv[1:])
    text = f"""
LinuxCNC 2.9 (Debian's linuxcnc-uspace, its trajectory planner in the uspace simulation)
against ours on the same programs under the same limits: T = 1 ms, feed capped at 200 mm/s,
acceleration 2500 mm/s^2 resultant (LinuxCNC: 1767.77 per axis), path tolerance G64 P0.01
(a line before the program, and the program's own G64 words replaced). Ours without a jerk
limit and with J = {JERK_MM_S3:g} mm/s^3 (the daemon's default). Motion times: LinuxCNC's servo
periods from the first to the last moving sample, ours set-points x T; deviations: largest
distance from the programmed path (our reader's blocks) of every sample / set-point
(planning.path_deviation). Load during the run (`uptime` at the end): {load}. LinuxCNC ran in
real time once per program (cached in {args.linuxcnc_cache.name}); its motion time does not
depend on the load (counted in servo periods), its wall time does. A run with
`--from-caches` plans nothing: it assembles what earlier runs of this script measured (both
caches; ours keyed by a hash of the measured src/nurbsmotion too).

{body}
"""
    short = ("Motion time of LinuxCNC 2.9 against ours, same programs and limits (T = 1 ms, F <= 200 mm/s, "
             "A = 2500 mm/s^2, G64 P0.01); ratio < 1: ours faster. Load at the end: " + load.split("load average:")[-1]
             + ".\n\n" + body.split("\n\n")[0])
    write_section("vs_linuxcnc", "Race against LinuxCNC", short, command, detail=text)


if __name__ == "__main__":
    main()
