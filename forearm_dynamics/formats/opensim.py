"""OpenSim's text tables (.mot motions, .sto states and results): read, map, write.

Format (OpenSim's Storage / TimeSeriesTable files): header lines, a line `endheader`,
one line of column labels (tab separated; the first is `time`), then one row of numbers
per line. Header lines worth reading: `inDegrees=yes|no` (angles and speeds in degrees),
`nRows=`, `nColumns=` (legacy .mot, checked when present). Two kinds of files:

- motion (.mot from Inverse Kinematics, or a hand-written one): labels are coordinate
  names (`elbow_flexion`);
- states (.sto from a simulation or `StatesTrajectory`): labels are paths
  (`/jointset/elbow/elbow_flexion/value`, `.../speed`, muscle states); a coordinate's
  value and speed are found by its name, the component before `value`/`speed`.

Every problem is one MotionError line naming the file and the row (1-based data row and
file line): no `endheader`, a row with the wrong number of values, a value that is not a
number or is NaN/inf, a time that does not increase.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..coordinate_map import SIDES, CoordinateMap  # noqa: F401 (re-exported: mot_to_bag, bag_export)
from ..description import JOINT_NAMES
from ..errors import MotionError


@dataclass
class Motion:
    path: Path
    kind: str  # 'motion' or 'states'
    in_degrees: bool
    header: dict[str, str]
    labels: list[str]  # data columns (time excluded)
    time: np.ndarray  # (N,) s
    data: np.ndarray  # (N, C) as in the file (degrees if in_degrees)


def _yes(value: str) -> bool | None:
    v = value.strip().lower()
    return True if v in ("yes", "true", "1") else False if v in ("no", "false", "0") else None


def read_motion(path: str | os.PathLike, in_degrees: bool | None = None) -> Motion:
    """Parse a .mot/.sto; `in_degrees` overrides (or supplies) the header's inDegrees."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise MotionError(f"{path}: cannot read ({exc.strerror or exc})") from None
    lines = text.splitlines()
    end = next((i for i, ln in enumerate(lines) if ln.strip().lower() == "endheader"), None)
    if end is None:
        raise MotionError(f"{path}: no 'endheader' line: not an OpenSim .mot/.sto (its header "
                          "must end with a line 'endheader')")
    header = {}
    for ln in lines[:end]:
        k, sep, v = ln.partition("=")
        if sep:
            header[k.strip()] = v.strip()
    deg = in_degrees if in_degrees is not None else _yes(header.get("inDegrees", ""))
    if deg is None:
        raise MotionError(f"{path}: the header has no inDegrees=yes|no; say which with "
                          "--in-degrees yes|no")
    k = end + 1
    while k < len(lines) and not lines[k].strip():
        k += 1
    if k >= len(lines):
        raise MotionError(f"{path}: no column labels after 'endheader'")
    labels = lines[k].split("\t") if "\t" in lines[k] else lines[k].split()
    labels = [s.strip() for s in labels]
    if not labels or labels[0].lower() != "time":
        raise MotionError(f"{path}: line {k + 1}: the first column must be 'time', got {labels[0]!r}")
    rows = []
    prev = -math.inf
    for i, ln in enumerate(lines[k + 1:], start=k + 2):
        if not ln.strip():
            continue
        parts = ln.split()
        r = len(rows) + 1
        if len(parts) != len(labels):
            raise MotionError(f"{path}: row {r} (line {i}) has {len(parts)} values, expected "
                              f"{len(labels)} (one per column label)")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            bad = next(p for p in parts if not _is_float(p))
            raise MotionError(f"{path}: row {r} (line {i}): {bad!r} is not a number") from None
        for lab, v in zip(labels, values, strict=True):
            if not math.isfinite(v):
                raise MotionError(f"{path}: row {r} (line {i}): {lab} is {v} (NaN or infinite)")
        if values[0] <= prev:
            raise MotionError(f"{path}: row {r} (line {i}): time {values[0]:g} does not increase "
                              f"(previous row {prev:g})")
        prev = values[0]
        rows.append(values)
    if not rows:
        raise MotionError(f"{path}: no data rows after the column labels")
    n_rows = header.get("nRows") or header.get("datarows")
    if n_rows is not None and n_rows.strip().isdigit() and int(n_rows) != len(rows):
        raise MotionError(f"{path}: the header says nRows={n_rows} but the file has {len(rows)} rows "
                          "(cut short?)")
    arr = np.array(rows, np.float64)
    kind = "states" if any(lab.startswith("/") for lab in labels[1:]) else "motion"
    return Motion(path, kind, bool(deg), header, labels[1:], arr[:, 0], arr[:, 1:])


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


@dataclass
class MappedMotion:
    """A motion in our joints (rad, rad/s), and what happened to every column."""

    time: np.ndarray
    q: np.ndarray  # (N, 20) JOINT_NAMES order
    qd: np.ndarray | None  # from a states file's speeds, when every mapped joint has one
    mapped: dict[str, str]  # our joint -> the column it came from
    held: dict[str, float]  # our joint -> rad
    not_modelled: list[str]
    unknown: list[str]
    notes: list[str] = field(default_factory=list)
    other_arm: list[str] = field(default_factory=list)  # the other side's arm columns
    as_given: np.ndarray | None = None  # (N, 20) q before the map's offsets (ranges.py)


def _coordinate_of(label: str) -> tuple[str, str]:
    """('elbow_flexion', 'value'|'speed'|'') of a column label (motion or states path)."""
    if label.startswith("/"):
        parts = [p for p in label.split("/") if p]
        if len(parts) >= 2 and parts[-1] in ("value", "speed"):
            return parts[-2], parts[-1]
        return parts[-1] if parts else label, "other"
    return label, "value"


def map_motion(m: Motion, cmap: CoordinateMap, side: str = "right") -> MappedMotion:
    """The file's columns as our joints (rad) for the arm `side`; a strict map's entry that
    names no column of the file is a MotionError (a typo must not hold a joint at 0)."""
    scale = math.pi / 180.0 if m.in_degrees else 1.0
    n = len(m.time)
    q = np.zeros((n, len(JOINT_NAMES)))
    qd = np.zeros((n, len(JOINT_NAMES)))
    mapped, speeds = {}, set()
    not_modelled, unknown, notes, other_arm = [], [], [], []
    entries, other = cmap.for_side(side), cmap.other_side(side)
    offsets = np.zeros(len(JOINT_NAMES))
    cmap.check_present(side, {_coordinate_of(lab)[0] for lab in m.labels}, f"column of {m.path}",
                       list(m.labels))
    for c, label in enumerate(m.labels):
        coord, what = _coordinate_of(label)
        hit = entries.get(coord)
        if hit is None and coord in other and what in ("value", "speed"):
            other_arm.append(label)
            continue
        if hit is None or what == "other":
            if what == "value" or what == "speed":
                (not_modelled if coord in cmap.not_modelled else unknown).append(label)
            elif m.kind == "states":
                not_modelled.append(label)  # muscle activations, fibre lengths...
            else:
                unknown.append(label)
            continue
        joint, sign, offset = hit
        j = JOINT_NAMES.index(joint)
        if what == "speed":
            qd[:, j] = sign * scale * m.data[:, c]
            speeds.add(joint)
            continue
        if joint in mapped:
            raise MotionError(f"{m.path}: columns {mapped[joint]!r} and {label!r} both give {joint}")
        q[:, j] = sign * scale * m.data[:, c] + offset
        offsets[j] = offset
        mapped[joint] = label
    if not mapped:
        raise MotionError(f"{m.path}: no column maps to a joint of the model (columns: "
                          f"{', '.join(m.labels[:6])}{' ...' if len(m.labels) > 6 else ''}); "
                          "see config/opensim_coordinates.yaml")
    held = {}
    for j, joint in enumerate(JOINT_NAMES):
        if joint not in mapped:
            held[joint] = cmap.hold.get(joint, 0.0)
            q[:, j] = held[joint]
    use_speeds = bool(speeds) and set(mapped) <= speeds
    if speeds and not use_speeds:
        notes.append("speeds given for some coordinates only: velocities left empty")
    return MappedMotion(m.time, q, qd if use_speeds else None, mapped, held, not_modelled, unknown,
                        notes, other_arm, q - offsets)


def write_table(path: str | os.PathLike, title: str, labels: list[str], time: np.ndarray,
                data: np.ndarray, *, sep: str = "\t", opensim: bool = True,
                stamps_ns: np.ndarray | None = None, notes: dict[str, str] | None = None) -> None:
    """An OpenSim-readable table (header, endheader, labels, rows) or, opensim=False, CSV.
    Values are written with repr (shortest exact float text); `stamps_ns`, if given, as an
    integer column `stamp_ns` after time. A value that is not finite (a σ not known while
    the estimate warms up is inf on the topic) is written `NaN` in a table, an empty cell in
    CSV (what OpenSim and CSV readers take for missing), never `inf`. `notes` {key: text}:
    header lines `key=text` of a table (OpenSim keeps them as metadata); CSV has no header
    but its column labels (the caller says them)."""
    path = Path(path)
    head = ["time", *(["stamp_ns"] if stamps_ns is not None else []), *labels]
    missing = "NaN" if opensim else ""
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        if opensim:
            extra = "".join(f"{k}={' '.join(v.split())}\n" for k, v in (notes or {}).items())
            fh.write(f"{title}\nversion=1\nnRows={len(time)}\nnColumns={len(head)}\n"
                     f"inDegrees=no\n{extra}endheader\n")
        fh.write(sep.join(head) + "\n")
        finite = np.isfinite(data)
        for k in range(len(time)):
            cells = [repr(float(time[k]))]
            if stamps_ns is not None:
                cells.append(str(int(stamps_ns[k])))
            if finite[k].all():
                cells += [repr(float(x)) for x in data[k]]
            else:
                cells += [repr(float(x)) if ok else missing for x, ok in zip(data[k], finite[k], strict=True)]
            fh.write(sep.join(cells) + "\n")
