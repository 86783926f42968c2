"""A program's blocks as compact records: columnar arrays, NURBS objects only for NURBS blocks.

``BlockRecords`` is the ``Sequence[Block]`` a reader gives ``Program.blocks``: row ``i`` holds
block ``i``'s kind, start and end (machine XYZ, mm), feed (NaN: the machine's), exact-stop
flag, G64 P tolerance (NaN: the machine's) and source line; arcs add a row of centre,
sweep, normal axis and rise (ArcShape's numbers), NURBS blocks an index into ``curves``.
``records[i]`` builds that Block on demand; its ``curve`` (line_curve, arc_curve or the
stored NurbsCurve) is built when asked for and never kept here. Lengths, extents and feed
statistics come from the arrays in closed form (``lengths_mm``, ``extent_mm``).

A block's SourceRef is the file, its line and that line's text: the text comes from the
program's own text (``SourceText``: the UTF-8 bytes and where each line starts, far smaller
than a string per line); the few blocks whose source is another text (the approach of a
start line) keep their SourceRef in ``source_overrides``.
"""

from __future__ import annotations

import array
import math
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence, overload

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import ArcShape, LineShape, arc_lengths_mm, arc_radii_mm, line_lengths_mm
from nurbsmotion.program.model import Block, BlockKind, SourceRef

KIND_CODES = {BlockKind.NURBS: 0, BlockKind.LINE: 1, BlockKind.RAPID: 2, BlockKind.ARC: 3}
KINDS = tuple(KIND_CODES)  # by code
NORMALS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # by normal axis (G19, G18, G17)
SHAPE_NONE = -1  # a line's row in shape_index: nothing more than its start and end
FORM_LINE, FORM_ARC, FORM_CURVE = 0, 1, 2  # what a block's geometry is kept as: LineShape, ArcShape, NurbsCurve
COLUMNS = ("kinds", "forms", "starts", "ends", "feeds_mm_s", "exact_stops", "blend_tolerances_mm",
           "smoothing_tolerances_mm", "lines", "shape_index")  # BlockRecords' arrays, in its constructor's order
ARC_COLUMNS = ("centres", "sweeps_rad", "normal_axes", "rises_mm")  # ArcRecords' arrays, in its order


@dataclass(frozen=True)
class SourceText:
    """Lines ``first_line``, ``first_line + 1``, ... of a program's text as UTF-8 bytes and
    the byte offset where each starts (lines split at '\\n', as the reader splits them);
    ``line(n)`` is line n (1-based), "" outside them."""

    data: bytes | NDArray[np.uint8]  # bytes, or a checked-program store entry's mapped bytes (service.checked_store)
    starts: NDArray[np.int64]  # one per line, then len(data) + 1
    first_line: int = 1

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled as bytes whatever holds them (a mapped file's array is not sent as a view)."""
        return (SourceText, (bytes(self.data), np.asarray(self.starts), self.first_line))

    @classmethod
    def of(cls, text: str) -> SourceText:
        data = text.encode("utf-8", "surrogatepass")
        breaks = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10)
        return cls(data, np.concatenate([[0], breaks + 1, [len(data) + 1]]).astype(np.int64))

    def line(self, number: int) -> str:
        k = number - self.first_line
        if not 0 <= k < len(self.starts) - 1:
            return ""
        return bytes(self.data[self.starts[k]:self.starts[k + 1] - 1]).decode("utf-8", "surrogatepass")

    @classmethod
    def joined(cls, parts: Sequence[SourceText | None]) -> SourceText | None:
        """Windows in line order as one text (None when any is missing): a window may repeat
        the last lines of the one before; lines between two windows (no block's) are empty."""
        texts = [p for p in parts if p is not None]
        if not texts or len(texts) != len(parts):
            return None
        data, starts = bytearray(), list[int]()
        next_line = texts[0].first_line
        for t in texts:
            lines = len(t.starts) - 1
            for _ in range(t.first_line - next_line):  # a gap: empty lines
                data += b"\n" if starts else b""
                starts.append(len(data))
            skip = max(next_line - t.first_line, 0)  # lines already there
            if skip >= lines:
                continue
            if starts:
                data += b"\n"
            base = len(data) - int(t.starts[skip])
            data += bytes(t.data[int(t.starts[skip]):])
            starts.extend((t.starts[skip:-1] + base).tolist())
            next_line = t.first_line + lines
        return cls(bytes(data), np.array(starts + [len(data) + 1], dtype=np.int64), texts[0].first_line)

    def window(self, first: int, last: int) -> SourceText:
        """Lines first..last only (a slice of the program's blocks carries no more text than its own)."""
        lo = min(max(first - self.first_line, 0), len(self.starts) - 1)
        hi = min(max(last - self.first_line + 1, lo), len(self.starts) - 1)
        begin = int(self.starts[lo])
        data = self.data[begin:max(int(self.starts[hi]) - 1, begin)]
        return SourceText(data, np.append(self.starts[lo:hi] - begin, len(data) + 1), self.first_line + lo)


class BlockRecords(Sequence[Block]):
    """The blocks of a program as arrays (module docstring); immutable once built."""

    def __init__(self, kinds: NDArray[np.uint8], forms: NDArray[np.uint8], starts: NDArray[np.float64],
                 ends: NDArray[np.float64], feeds_mm_s: NDArray[np.float64], exact_stops: NDArray[np.bool_],
                 blend_tolerances_mm: NDArray[np.float64], smoothing_tolerances_mm: NDArray[np.float64],
                 lines: NDArray[np.int64], shape_index: NDArray[np.int64], arcs: ArcRecords, curves: tuple[NurbsCurve, ...], file: str, text: SourceText | None,
                 source_overrides: dict[int, SourceRef]) -> None:
        self.kinds, self.forms, self.starts, self.ends = kinds, forms, starts, ends
        self.feeds_mm_s, self.exact_stops, self.blend_tolerances_mm = feeds_mm_s, exact_stops, blend_tolerances_mm
        self.smoothing_tolerances_mm = smoothing_tolerances_mm  # G64 Q; NaN: the machine's
        self.lines, self.shape_index, self.arcs, self.curves = lines, shape_index, arcs, curves
        self.file, self.text, self.source_overrides = file, text, source_overrides
        for values in (kinds, forms, starts, ends, feeds_mm_s, exact_stops, blend_tolerances_mm, smoothing_tolerances_mm,
                       lines, shape_index):
            values.setflags(write=False)

    @classmethod
    def of_blocks(cls, blocks: Sequence[Block]) -> BlockRecords:
        """Records of any blocks (a YAML curve program's, a test's): as they are if they are records."""
        if isinstance(blocks, BlockRecords):
            return blocks
        builder = RecordsBuilder(blocks[0].source.file if blocks else "")
        for b in blocks:
            builder.add(b.kind, b.shape, b.feed_mm_s, b.source, b.exact_stop, b.blend_tolerance_mm,
                        b.smoothing_tolerance_mm)
        return builder.build(None)

    @classmethod
    def concatenate(cls, parts: Sequence[BlockRecords]) -> BlockRecords:
        """One program's records from its slices in order (what a ProgramBlocks message
        carries): the columns joined, arc rows and curve indexes shifted, the text windows
        joined when they are consecutive (a slice's lines follow the previous one's)."""
        if not parts:
            return RecordsBuilder("").build(None)
        arc_offsets = np.cumsum([0] + [len(p.arcs.sweeps_rad) for p in parts[:-1]])
        curve_offsets = np.cumsum([0] + [len(p.curves) for p in parts[:-1]])
        index = []
        for part, arcs_before, curves_before in zip(parts, arc_offsets, curve_offsets):
            shifted = part.shape_index.copy()
            shifted[part.forms == FORM_ARC] += arcs_before
            shifted[part.forms == FORM_CURVE] += curves_before
            index.append(shifted)
        overrides: dict[int, SourceRef] = {}
        first = 0
        for part in parts:
            overrides.update({first + i: ref for i, ref in part.source_overrides.items()})
            first += len(part)
        arcs = ArcRecords(np.concatenate([p.arcs.centres for p in parts]), np.concatenate([p.arcs.sweeps_rad for p in parts]),
                          np.concatenate([p.arcs.normal_axes for p in parts]), np.concatenate([p.arcs.rises_mm for p in parts]))

        def joined(name: str) -> NDArray[Any]:
            return np.concatenate([getattr(p, name) for p in parts])

        return BlockRecords(joined("kinds"), joined("forms"), joined("starts"), joined("ends"), joined("feeds_mm_s"),
                            joined("exact_stops"), joined("blend_tolerances_mm"), joined("smoothing_tolerances_mm"),
                            joined("lines"), np.concatenate(index),
                            arcs, tuple(c for p in parts for c in p.curves), parts[0].file,
                            SourceText.joined([p.text for p in parts]), overrides)

    def columns(self) -> dict[str, NDArray[Any]]:
        """Every array of the records by name (COLUMNS, then ARC_COLUMNS as ``arc_<name>``): what
        a checked-program store entry keeps as raw bytes (service.checked_store)."""
        out = {name: getattr(self, name) for name in COLUMNS}
        out.update({f"arc_{name}": getattr(self.arcs, name) for name in ARC_COLUMNS})
        return out

    @classmethod
    def from_columns(cls, columns: dict[str, NDArray[Any]], curves: tuple[NurbsCurve, ...], file: str,
                     text: SourceText | None, source_overrides: dict[int, SourceRef]) -> BlockRecords:
        """The records of :meth:`columns` (arrays of a mapped file work as they are)."""
        arcs = ArcRecords(*(columns[f"arc_{name}"] for name in ARC_COLUMNS))
        return cls(*(columns[name] for name in COLUMNS), arcs, curves, file, text,  # type: ignore[arg-type, call-arg]
                   source_overrides)

    def __len__(self) -> int:
        return len(self.kinds)

    @overload
    def __getitem__(self, index: int) -> Block: ...

    @overload
    def __getitem__(self, index: slice) -> BlockRecords: ...

    def __getitem__(self, index: int | slice) -> Block | BlockRecords:
        if isinstance(index, slice):
            return self.rows(np.arange(*index.indices(len(self))))
        n = len(self)
        i = int(index) + n if index < 0 else int(index)
        if not 0 <= i < n:
            raise IndexError(f"block {index} of {n}")
        return self.block(i)

    def __iter__(self) -> Iterator[Block]:
        return (self.block(i) for i in range(len(self)))

    def __eq__(self, other: object) -> bool:
        """Records equal records holding the same numbers; a tuple or list of Blocks is equal
        when it holds these blocks (Blocks compare by identity: only when both are empty)."""
        if isinstance(other, BlockRecords):
            return self is other or (self.signature() == other.signature())
        if isinstance(other, (tuple, list)):
            return len(other) == len(self) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def signature(self) -> tuple[object, ...]:
        """Every number and source of the records, comparable (==)."""
        arrays = (self.kinds, self.forms, self.starts, self.ends, self.feeds_mm_s, self.exact_stops,
                  self.blend_tolerances_mm, self.smoothing_tolerances_mm, self.lines, self.shape_index,
                  self.arcs.centres, self.arcs.sweeps_rad,
                  self.arcs.normal_axes, self.arcs.rises_mm)
        curves = tuple((c.degree, c.control_points.tobytes(), c.weights.tobytes(), c.knots.tobytes()) for c in self.curves)
        text = None if self.text is None else (bytes(self.text.data), self.text.starts.tobytes(), self.text.first_line)
        return (tuple(np.ascontiguousarray(a).tobytes() for a in arrays), curves, self.file, text, self.source_overrides)

    def __repr__(self) -> str:
        return f"BlockRecords({len(self)} blocks, {len(self.arcs.sweeps_rad)} arcs, {len(self.curves)} NURBS)"

    def source(self, i: int) -> SourceRef:
        ref = self.source_overrides.get(i)
        if ref is not None:
            return ref
        line = int(self.lines[i])
        return SourceRef(self.file, line, self.text.line(line).strip() if self.text is not None else "")

    def shape(self, i: int) -> NurbsCurve | LineShape | ArcShape:
        form, k = self.forms[i], int(self.shape_index[i])
        if form == FORM_CURVE:
            return self.curves[k]
        start, end = self.starts[i].copy(), self.ends[i].copy()
        if form == FORM_ARC:
            a = self.arcs
            return ArcShape(start, end, a.centres[k].copy(), float(a.sweeps_rad[k]), NORMALS[a.normal_axes[k]],
                            float(a.rises_mm[k]))
        return LineShape(start, end)

    def block(self, i: int) -> Block:
        feed, blend = float(self.feeds_mm_s[i]), float(self.blend_tolerances_mm[i])
        smoothing = float(self.smoothing_tolerances_mm[i])
        return Block(KINDS[self.kinds[i]], self.shape(i), None if math.isnan(feed) else feed, self.source(i),
                     bool(self.exact_stops[i]), None if math.isnan(blend) else blend,
                     None if math.isnan(smoothing) else smoothing)

    def rows(self, rows: NDArray[np.int64]) -> BlockRecords:
        """The blocks of ``rows`` (in that order) as records of their own: their arcs and curves only."""
        forms = self.forms[rows]
        is_arc, is_curve = forms == FORM_ARC, forms == FORM_CURVE
        arc_rows, curve_rows = self.shape_index[rows[is_arc]], self.shape_index[rows[is_curve]]
        index = np.full(len(rows), SHAPE_NONE, dtype=np.int64)
        index[is_arc] = np.arange(len(arc_rows))
        index[is_curve] = np.arange(len(curve_rows))
        overrides = {j: self.source_overrides[i] for j, i in enumerate(rows.tolist()) if i in self.source_overrides} \
            if self.source_overrides else {}
        return BlockRecords(self.kinds[rows], forms, self.starts[rows], self.ends[rows], self.feeds_mm_s[rows],
                            self.exact_stops[rows], self.blend_tolerances_mm[rows], self.smoothing_tolerances_mm[rows],
                            self.lines[rows], index,
                            self.arcs.rows(arc_rows), tuple(self.curves[k] for k in curve_rows.tolist()), self.file,
                            self.text_of(self.lines[rows]), overrides)

    def text_of(self, lines: NDArray[np.int64]) -> SourceText | None:
        """The source text of these lines only."""
        if self.text is None or not len(lines):
            return None
        return self.text.window(int(lines.min()), int(lines.max()))

    # ---- the checks, in closed form over the arrays --------------------------------------------
    def lengths_mm(self) -> NDArray[np.float64]:
        """Every block's length: |end - start| for lines, sqrt((r sweep)^2 + rise^2) for arcs,
        the NURBS arc length (Gauss quadrature) for NURBS curves."""
        out = line_lengths_mm(self.starts, self.ends)
        arcs = np.flatnonzero(self.forms == FORM_ARC)
        if len(arcs):
            a = self.arcs
            out[arcs] = arc_lengths_mm(self.starts[arcs], a.centres, a.normals(), a.sweeps_rad, a.rises_mm)
        for i in np.flatnonzero(self.forms == FORM_CURVE).tolist():
            out[i] = self.curves[int(self.shape_index[i])].length
        return out

    def boxes_mm(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(lows, highs), each (n, 3): per block a box that holds its curve, from the columns in
        closed form: a line's ends, an arc's or helix' extents (ArcRecords.extents_mm, all arcs
        at once: building a curve per arc took ~30 s of a 10^6-line check), a NURBS block's
        control points (the box of their convex hull, which holds the curve)."""
        lows, highs = np.minimum(self.starts, self.ends), np.maximum(self.starts, self.ends)
        arcs = np.flatnonzero(self.forms == FORM_ARC)
        if len(arcs):
            lows[arcs], highs[arcs] = self.arcs.rows(self.shape_index[arcs]).extents_mm(self.starts[arcs], self.ends[arcs])
        for i in np.flatnonzero(self.forms == FORM_CURVE).tolist():
            points = self.curves[int(self.shape_index[i])].control_points
            lows[i], highs[i] = points.min(axis=0), points.max(axis=0)
        return lows, highs

    def extent_mm(self, curve_points: Callable[[NurbsCurve], NDArray[np.float64]]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(min, max) XYZ over the path: the end points, each arc's extremes (ArcRecords.extents_mm)
        and ``curve_points(curve)`` of every NURBS curve. No blocks: +inf and -inf."""
        low = np.minimum(self.starts.min(axis=0, initial=np.inf), self.ends.min(axis=0, initial=np.inf))
        high = np.maximum(self.starts.max(axis=0, initial=-np.inf), self.ends.max(axis=0, initial=-np.inf))
        arcs = np.flatnonzero(self.forms == FORM_ARC)
        if len(arcs):
            arc_low, arc_high = self.arcs.extents_mm(self.starts[arcs], self.ends[arcs])
            low, high = np.minimum(low, arc_low.min(axis=0)), np.maximum(high, arc_high.max(axis=0))
        for curve in self.curves:
            points = curve_points(curve)
            low, high = np.minimum(low, points.min(axis=0)), np.maximum(high, points.max(axis=0))
        return low, high


@dataclass(frozen=True)
class ArcRecords:
    """The arcs' rows (ArcShape's numbers besides start and end), in block order."""

    centres: NDArray[np.float64]  # (m, 3)
    sweeps_rad: NDArray[np.float64]  # signed: positive counter-clockwise about the normal
    normal_axes: NDArray[np.uint8]  # 2: +Z (G17), 1: +Y (G18), 0: +X (G19)
    rises_mm: NDArray[np.float64]

    def rows(self, index: NDArray[np.int64]) -> ArcRecords:
        return ArcRecords(self.centres[index], self.sweeps_rad[index], self.normal_axes[index], self.rises_mm[index])

    def normals(self) -> NDArray[np.float64]:
        return np.asarray(NORMALS)[self.normal_axes]

    def extents_mm(self, starts: NDArray[np.float64], ends: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(lows, highs), each (m, 3): every arc's min and max XYZ, of the curve arc_curve builds.

        In its plane, axes (a, b) = (n+1, n+2) mod 3 for normal axis n, the ideal arc (the
        curve with its computed end: the exact circle in projection, the helix' height
        between the start's and start + rise) reaches its ends and c +- r where the swept
        angle phi = atan2(b - cb, a - ca) (growing with a positive sweep) passes 0, 90, 180
        or 270 deg. arc_curve moves its last control point to the programmed end, by d =
        end - ideal end (the reader's radius tolerance at most): the curve is the ideal one
        plus R(u) d with R in [0, 1], so the box grows by min(d, 0) and max(d, 0)."""
        radii = arc_radii_mm(starts, self.centres, self.normals())
        lows, highs = starts.copy(), starts.copy()
        deviation = np.zeros_like(starts)
        rows = np.arange(len(starts))
        for n in range(3):
            sel = np.flatnonzero(self.normal_axes == n)
            if not len(sel):
                continue
            a, b = (n + 1) % 3, (n + 2) % 3
            c, s, r, sweep = self.centres[sel], starts[sel], radii[sel], self.sweeps_rad[sel]
            phi0 = np.arctan2(s[:, b] - c[:, b], s[:, a] - c[:, a])
            ideal_end = np.empty((len(sel), 3))
            ideal_end[:, a] = c[:, a] + r * np.cos(phi0 + sweep)
            ideal_end[:, b] = c[:, b] + r * np.sin(phi0 + sweep)
            ideal_end[:, n] = s[:, n] + self.rises_mm[sel]
            lows[sel] = np.minimum(lows[sel], ideal_end)
            highs[sel] = np.maximum(highs[sel], ideal_end)
            deviation[sel] = ends[sel] - ideal_end
            first = np.where(sweep >= 0, phi0, phi0 + sweep)  # the swept interval [first, first + |sweep|]
            for angle, axis, sign in ((0.0, a, 1.0), (math.pi / 2, b, 1.0), (math.pi, a, -1.0), (1.5 * math.pi, b, -1.0)):
                passed = np.mod(angle - first, 2 * math.pi) <= np.abs(sweep)
                at, value = rows[sel[passed]], c[passed, axis] + sign * r[passed]
                if sign > 0:
                    highs[at, axis] = np.maximum(highs[at, axis], value)
                else:
                    lows[at, axis] = np.minimum(lows[at, axis], value)
        return lows + np.minimum(deviation, 0.0), highs + np.maximum(deviation, 0.0)


EMPTY_ARCS = ArcRecords(np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.uint8), np.zeros(0))


class RecordsBuilder:
    """Blocks appended one at a time (a reader's), then ``build`` into BlockRecords."""

    def __init__(self, file: str, line_text: Callable[[int], str] | None = None) -> None:
        self.file = file
        self.line_text = line_text  # the raw text of line n, to tell which SourceRefs are the line's own
        self.kinds = array.array("B")
        self.forms = array.array("B")
        self.points = array.array("d")  # start xyz, end xyz per block
        self.feeds = array.array("d")
        self.exact = array.array("B")
        self.blends = array.array("d")
        self.smoothings = array.array("d")  # G64 Q per block; NaN: the machine's
        self.lines = array.array("q")
        self.shape_index = array.array("q")
        self.arc_values = array.array("d")  # centre xyz, sweep, rise per arc
        self.arc_axes = array.array("B")
        self.curves: list[NurbsCurve] = []
        self.overrides: dict[int, SourceRef] = {}
        self.arcs_reserved = 0  # reserve_arc's rows not given yet (add_arc_row)

    def __len__(self) -> int:
        return len(self.kinds)

    def add(self, kind: BlockKind, shape: NurbsCurve | LineShape | ArcShape, feed_mm_s: float | None, source: SourceRef,
            exact_stop: bool, blend_tolerance_mm: float | None, smoothing_tolerance_mm: float | None = None) -> None:
        """One block; a LineShape or ArcShape is kept as numbers, a NurbsCurve as itself."""
        if isinstance(shape, NurbsCurve):
            start, end = shape.control_points[0].tolist(), shape.control_points[-1].tolist()
        else:
            start, end = shape.start.tolist(), shape.end.tolist()
        if len(start) != 3:
            raise ValueError(f"a block has 3 coordinates X Y Z, got {len(start)}")
        if isinstance(shape, NurbsCurve):
            form, index = FORM_CURVE, len(self.curves)
            self.curves.append(shape)
        elif isinstance(shape, ArcShape):
            form, index = FORM_ARC, len(self.arc_axes)
            self.arc_values.extend((*shape.centre.tolist(), shape.sweep_rad, shape.rise_mm))
            self.arc_axes.append(NORMALS.index(tuple(shape.normal)))
        else:
            form, index = FORM_LINE, SHAPE_NONE
        self._row(KIND_CODES[kind], form, index, (*start, *end), math.nan if feed_mm_s is None else feed_mm_s,
                  exact_stop, blend_tolerance_mm, smoothing_tolerance_mm, source.line)
        if not self.is_own_line(source):
            self.overrides[len(self.kinds) - 1] = source

    def add_line_numbers(self, kind_code: int, sx: float, sy: float, sz: float, ex: float, ey: float, ez: float,
                         feed_mm_s: float, exact_stop: bool, blend_tolerance_mm: float | None,
                         smoothing_tolerance_mm: float | None, line: int) -> None:
        """A line or rapid (``kind_code``: KIND_CODES) of this file's line ``line`` (its own
        text), from plain numbers: gcode_fast's path, without building a shape or SourceRef.
        ``feed_mm_s``: NaN for None."""
        self._row(kind_code, FORM_LINE, SHAPE_NONE, (sx, sy, sz, ex, ey, ez), feed_mm_s, exact_stop,
                  blend_tolerance_mm, smoothing_tolerance_mm, line)

    def reserve_arc(self, sx: float, sy: float, sz: float, ex: float, ey: float, ez: float, feed_mm_s: float,
                    exact_stop: bool, blend_tolerance_mm: float | None, smoothing_tolerance_mm: float | None,
                    line: int) -> None:
        """An arc of this file's line ``line`` whose row of numbers add_arc_row gives later, in
        the order reserved (gcode_fast computes a run's arcs together)."""
        self._row(KIND_CODES[BlockKind.ARC], FORM_ARC, len(self.arc_axes) + self.arcs_reserved,
                  (sx, sy, sz, ex, ey, ez), feed_mm_s, exact_stop, blend_tolerance_mm, smoothing_tolerance_mm, line)
        self.arcs_reserved += 1

    def _row(self, kind_code: int, form: int, shape_index: int, points: tuple[float, ...], feed_mm_s: float,
             exact_stop: bool, blend_tolerance_mm: float | None, smoothing_tolerance_mm: float | None,
             line: int) -> None:
        """One block's numbers in every column (NaN for a tolerance of None: the machine's)."""
        self.kinds.append(kind_code)
        self.forms.append(form)
        self.shape_index.append(shape_index)
        self.points.extend(points)
        self.feeds.append(feed_mm_s)
        self.exact.append(exact_stop)
        self.blends.append(math.nan if blend_tolerance_mm is None else blend_tolerance_mm)
        self.smoothings.append(math.nan if smoothing_tolerance_mm is None else smoothing_tolerance_mm)
        self.lines.append(line)

    def add_arc_row(self, centre: Sequence[float], sweep_rad: float, rise_mm: float, normal_axis: int) -> None:
        """The numbers of the first arc reserved and not given yet."""
        self.arc_values.extend((centre[0], centre[1], centre[2], sweep_rad, rise_mm))
        self.arc_axes.append(normal_axis)
        self.arcs_reserved -= 1

    def truncate(self, blocks: int, arcs: int) -> None:
        """Back to the first ``blocks`` blocks, holding the first ``arcs`` arcs (no curve added
        since); arcs reserved and not given are dropped."""
        for values in (self.kinds, self.forms, self.feeds, self.exact, self.blends, self.smoothings, self.lines,
                       self.shape_index):
            del values[blocks:]
        del self.points[6 * blocks:]
        del self.arc_values[5 * arcs:]
        del self.arc_axes[arcs:]
        self.arcs_reserved = 0
        for i in [i for i in self.overrides if i >= blocks]:
            del self.overrides[i]

    def is_own_line(self, source: SourceRef) -> bool:
        """The SourceRef is (file, line, that line's text stripped): nothing to keep but the line."""
        if source.file != self.file or self.line_text is None:
            return False
        return source.text == self.line_text(source.line).strip()

    def mark_exact_stop_last(self) -> None:
        self.exact[-1] = True

    @property
    def last_exact_stop(self) -> bool:
        return bool(self.exact[-1])

    def build(self, text: SourceText | None) -> BlockRecords:
        n = len(self.kinds)
        points = np.frombuffer(self.points, dtype=np.float64).reshape(n, 2, 3) if n else np.zeros((0, 2, 3))
        arcs = EMPTY_ARCS
        if len(self.arc_axes):
            values = np.frombuffer(self.arc_values, dtype=np.float64).reshape(-1, 5)
            arcs = ArcRecords(values[:, :3], values[:, 3], np.frombuffer(self.arc_axes, dtype=np.uint8), values[:, 4])
        return BlockRecords(np.frombuffer(self.kinds, dtype=np.uint8), np.frombuffer(self.forms, dtype=np.uint8),
                            points[:, 0], points[:, 1],
                            np.frombuffer(self.feeds, dtype=np.float64), np.frombuffer(self.exact, dtype=np.uint8).astype(bool),
                            np.frombuffer(self.blends, dtype=np.float64), np.frombuffer(self.smoothings, dtype=np.float64),
                            np.frombuffer(self.lines, dtype=np.int64),
                            np.frombuffer(self.shape_index, dtype=np.int64), arcs, tuple(self.curves), self.file, text,
                            self.overrides)
