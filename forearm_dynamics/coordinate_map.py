"""OpenSim coordinate names -> our joints (config/opensim_coordinates.yaml): the one reader.

Why in the core: every path that meets an OpenSim model or table needs the same map, names,
signs and offsets (formats/opensim.py for .mot/.sto files, muscles/source_osim.py for an
.osim model's muscles), and the muscle layer sits below formats/. One source per fact: the
YAML file; one reader of it: CoordinateMap.load.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .description import JOINT_NAMES
from .errors import MotionError
from .paths import config_file

SIDES = ("right", "left")


@dataclass(frozen=True)
class CoordinateMap:
    """config/opensim_coordinates.yaml: OpenSim name -> (our joint, sign, offset rad).

    An entry may say `side: right|left` (full-body models name both arms: `elbow_flex_r`,
    `elbow_flex_l`); map_motion uses the entries of the side asked for and reports the other
    arm's columns as such. `strict` (a map the user gave with --map): every entry of the side
    must name a column of the file, so a typo is an error, not a joint silently held at 0.
    """

    coordinates: dict[str, tuple[str, float, float]]
    not_modelled: frozenset[str]
    hold: dict[str, float]  # rad
    sides: dict[str, str] = field(default_factory=dict)  # OpenSim name -> 'right'|'left'
    path: Path | None = None
    strict: bool = False

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> CoordinateMap:
        """The package's map (lenient: it names many models' columns), or the user's
        (strict: every entry must be in the file)."""
        strict = path is not None
        path = Path(path) if path is not None else config_file("opensim_coordinates.yaml")
        try:
            with open(path, encoding="utf-8") as fh:
                cfg = yaml.safe_load(fh) or {}
        except OSError as exc:
            raise MotionError(f"{path}: cannot read the coordinate map ({exc.strerror or exc})") from None
        except yaml.YAMLError as exc:
            raise MotionError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
        coords, sides = {}, {}
        for name, spec in (cfg.get("coordinates") or {}).items():
            joint = spec.get("joint") if isinstance(spec, dict) else None
            if joint not in JOINT_NAMES:
                raise MotionError(f"{path}: coordinate {name} maps to unknown joint {joint!r} "
                                  f"(joints: {', '.join(JOINT_NAMES[:4])}, ...)")
            coords[str(name)] = (joint, float(spec.get("sign", 1)),
                                 math.radians(float(spec.get("offset_deg", 0))))
            if "side" in spec:
                if spec["side"] not in SIDES:
                    raise MotionError(f"{path}: coordinate {name}: side {spec['side']!r} is not "
                                      "right or left")
                sides[str(name)] = spec["side"]
        for j in JOINT_NAMES:  # our own names map to themselves
            coords.setdefault(j, (j, 1.0, 0.0))
        hold = {str(k): math.radians(float(v)) for k, v in (cfg.get("hold_posture_deg") or {}).items()}
        unknown = sorted(set(hold) - set(JOINT_NAMES))
        if unknown:
            raise MotionError(f"{path}: hold_posture_deg names unknown joints {unknown}")
        return cls(coords, frozenset(str(x) for x in cfg.get("not_modelled") or ()), hold,
                   sides, path, strict)

    def opensim_name(self, joint: str) -> tuple[str, float]:
        """The OpenSim coordinate of one of our joints (first MoBL/ARMS name) and its sign."""
        for name, (j, sign, _off) in self.coordinates.items():
            if j == joint and name != joint and name not in self.sides:
                return name, sign
        return joint, 1.0

    def for_side(self, side: str) -> dict[str, tuple[str, float, float]]:
        """The entries that apply to one arm: those of that side and those without a side."""
        return {n: v for n, v in self.coordinates.items() if self.sides.get(n, side) == side}

    def other_side(self, side: str) -> frozenset[str]:
        return frozenset(n for n, s in self.sides.items() if s != side)

    def check_present(self, side: str, present, what: str, listing: list[str]) -> None:
        """A strict map (a user's own): every entry for `side` must name something in
        `present` (or be one of our joint names), else MotionError in one line naming the
        entries and `what` they were looked for in (a .mot's columns, an .osim's
        coordinates), with the first of `listing`. A default map is not strict: no check."""
        if not self.strict:
            return
        present = set(present)
        absent = [n for n in self.for_side(side) if n not in present and n not in JOINT_NAMES]
        if absent:
            raise MotionError(f"{self.path}: map entr{'y' if len(absent) == 1 else 'ies'} "
                              f"{', '.join(absent[:5])}{' ...' if len(absent) > 5 else ''} name no "
                              f"{what} (a typo? there: {', '.join(listing[:8])}"
                              f"{' ...' if len(listing) > 8 else ''})")
