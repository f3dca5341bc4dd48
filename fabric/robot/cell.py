"""The cell configuration: robot, tool, table, plate and home, read strictly from a TOML file.

Frames (the paper's Table II; every frame hangs from the robot base, mm / deg):

* ``base_T``: the robot base in the station (world) frame; identity in the
  paper's cell. Everything below is expressed in the **robot base frame**.
* table: its reference point is the centre of the table's **top face**; the
  box ``size_mm`` hangs below it. The robot stands on the table top, so the
  base z = 0 is the table top level (Table II: table at (310, 0, 0)).
* plate: its reference point is the centre of the plate's **bottom face**
  (Table II: (600, 0, 0), i.e. 600 mm in front of A1, lying on the table).
  With the 250 x 250 x 10 plate there, its top is at z = 10 mm and the far
  corner (725, +-125) puts the IRB 140's wrist centre (215 mm above the nozzle
  tip with the nozzle vertical) 678 mm from the shoulder, inside the 740 mm
  arm length with margin, and the near edge (x = 475) 424 mm from it, well
  outside the 20 mm inner limit: the whole plate top is reachable with a
  vertical nozzle, so z = 0 is kept as in the paper.
* work object (``wobj_T``): the corner of the plate's top face at (x min,
  y min), axes parallel to the plate; G-code bed coordinates (0..250, 0..250,
  z up from the plate surface) land on the plate unchanged.
* ``true_plate_T`` = ``plate_T @ true_offset``: where the twin's plate really
  is (the offset is expressed in the nominal plate frame); calibration
  recovers it by probing.

Unknown sections or keys are a ``ConfigError`` naming them; values are
type- and range-checked when read.
"""
from __future__ import annotations

import hashlib
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fabric.drivers.address import parse_robot
from fabric.robot import frames
from fabric.robot.brands import NATIVE_EXPORTS
from fabric.robot.model import RobotModel, ToolGeometry
from fabric.wire.errors import ConfigError, NotFound, ValidationError

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

__all__ = ["Cell", "CELLS_DIR", "PACKAGE_DIR", "DEFAULT_CELL", "NATIVE_EXPORTS", "builtin_cell_names"]

PACKAGE_DIR = Path(__file__).resolve().parent.parent
CELLS_DIR = PACKAGE_DIR / "cells"
DEFAULT_CELL = "irb140"          # the built-in cell a service uses when given no cell file


def builtin_cell_names() -> list[str]:
    """The cells shipped in ``fabric/cells/`` by name (``irb140``, ``kr6r700``, ``ur10``, ``ur5``)."""
    return sorted(p.stem for p in CELLS_DIR.glob("*.toml"))

# section -> allowed keys (a trailing "." marks a sub-table)
_SCHEMA: dict[str, set[str]] = {
    "cell": {"name", "description"},
    "robot": {"urdf", "example_robot_data", "flange_frame", "name", "brand", "redundancy_joint", "base_xyz_mm",
              "base_rpy_deg", "controller", "deviation_bound_mm"},
    "tool": {"tcp_xyz_mm", "tcp_rpy_deg", "body_diameter_mm", "body_length_mm", "nozzle_diameter_mm",
             "nozzle_length_mm", "nozzle_clearance_mm", "tip_diameter_mm", "taper_length_mm"},
    "table": {"size_mm", "xyz_mm", "rpy_deg"},
    "plate": {"size_mm", "xyz_mm", "rpy_deg", "true_offset."},
    "plate.true_offset": {"xyz_mm", "rpy_deg"},
    "home": {"joints_deg"},
    "approach": {"height_mm", "speed_mm_s", "zone"},
    "limits": {"lower_deg", "upper_deg", "vel_deg_s", "acc_deg_s2", "jerk_deg_s3"},
}
_REQUIRED = ("cell", "robot", "tool", "table", "plate", "home", "approach")


class _Reader:
    """Typed, range-checked access to one TOML section; errors name ``file`` and ``section.key``."""

    def __init__(self, data: dict[str, Any], section: str, source: str) -> None:
        self.data, self.section, self.source = data, section, source

    def _err(self, key: str, msg: str, value: Any = None) -> ConfigError:
        name = f"{self.section}.{key}"
        return ConfigError(f"{self.source}: {name}: {msg}", file=self.source, key=name, value=value)

    def has(self, key: str) -> bool:
        return key in self.data

    def num(self, key: str, default: float | None = None, lo: float = -np.inf, hi: float = np.inf) -> float:
        if key not in self.data:
            if default is None:
                raise self._err(key, "missing")
            return float(default)
        v = self.data[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise self._err(key, f"expected a number, got {v!r}", v)
        if not lo <= v <= hi:
            raise self._err(key, f"{v} out of range [{lo}, {hi}]", v)
        return float(v)

    def vec(self, key: str, n: int | None = 3, default: list[float] | None = None,
            lo: float = -np.inf, hi: float = np.inf) -> np.ndarray:
        if key not in self.data:
            if default is None:
                raise self._err(key, "missing")
            return np.array(default, dtype=float)
        v = self.data[key]
        if not isinstance(v, list) or (n is not None and len(v) != n) or \
                not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            raise self._err(key, f"expected {n or 'a list of'} numbers, got {v!r}", v)
        arr = np.array(v, dtype=float)
        if not np.all(np.isfinite(arr)) or np.any(arr < lo) or np.any(arr > hi):
            raise self._err(key, f"values out of range [{lo}, {hi}]: {v}", v)
        return arr

    def text(self, key: str, default: str | None = None) -> str:
        if key not in self.data:
            if default is None:
                raise self._err(key, "missing")
            return default
        v = self.data[key]
        if not isinstance(v, str) or not v.strip():
            raise self._err(key, f"expected a non-empty string, got {v!r}", v)
        return v


def _check_keys(doc: dict[str, Any], source: str) -> None:
    for section, body in doc.items():
        if section not in _SCHEMA or not isinstance(body, dict):
            raise ConfigError(f"{source}: unknown section [{section}]", file=source, key=section)
        for key, val in body.items():
            if f"{key}." in _SCHEMA[section] and isinstance(val, dict):
                sub = f"{section}.{key}"
                for k in val:
                    if k not in _SCHEMA[sub]:
                        raise ConfigError(f"{source}: unknown key {sub}.{k}", file=source, key=f"{sub}.{k}")
            elif key not in _SCHEMA[section]:
                raise ConfigError(f"{source}: unknown key {section}.{key}", file=source, key=f"{section}.{key}")
    for section in _REQUIRED:
        if section not in doc:
            raise ConfigError(f"{source}: missing section [{section}]", file=source, key=section)


def _pose(xyz_mm: np.ndarray, rpy_deg: np.ndarray) -> np.ndarray:
    return frames.xyzrpy_to_T(xyz_mm, rpy_deg)


def _xyzrpy(T: np.ndarray) -> dict[str, list[float]]:
    xyz, rpy = frames.T_to_xyzrpy(T)
    return {"xyz_mm": [round(float(v), 6) + 0.0 for v in xyz], "rpy_deg": [round(float(v), 6) + 0.0 for v in rpy]}


@dataclass
class Cell:
    """A robot cell: the robot model with its tool, the table and plate, home and approach settings."""

    name: str
    robot: RobotModel
    base_T: np.ndarray
    table_size_mm: np.ndarray
    table_T: np.ndarray
    plate_size_mm: np.ndarray
    plate_T: np.ndarray
    true_plate_T: np.ndarray
    home_q_rad: np.ndarray
    approach_height_mm: float
    approach_speed_mm_s: float
    approach_zone_mm: float
    source_path: str | None = None
    robot_source: str = ""
    description: str = ""
    brand: str = ""                  # the robot's maker (``NATIVE_EXPORTS``): which export its controller runs
    controller: str = ""             # the robot controller the station drives (KIND:HOST; "": the twin alone)
    deviation_bound_mm: float = 0.5  # a print on the robot pauses when its TCP leaves the commanded path by more
    raw: dict[str, Any] = field(default_factory=dict, repr=False)

    # Loading -----------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> Cell:
        """Read a cell file; relative robot paths resolve against the fabric package, then the file's folder."""
        p = Path(path)
        if not p.is_file():
            raise NotFound(f"cell file not found: {p}", file=str(p))
        return cls.from_toml_text(p.read_text(), p.resolve().parent, source=str(p))

    @classmethod
    def load_or_builtin(cls, path: str | Path | None) -> Cell:
        """The cell a ``--cell-config NAME|FILE`` option names.

        A file that exists is read; otherwise a bare name (no folder, no
        ``.toml``) is a built-in cell (``builtin_cell_names()``); None or empty
        is the built-in ``DEFAULT_CELL``. Anything else is ``NotFound``.
        """
        if not path:
            return cls.builtin(DEFAULT_CELL)
        p = Path(path)
        if p.is_file() or p.suffix or len(p.parts) > 1:
            return cls.load(p)
        return cls.builtin(str(path))

    @classmethod
    def builtin(cls, name: str = DEFAULT_CELL) -> Cell:
        """One of the cells shipped in ``fabric/cells/`` by name (``builtin_cell_names()``)."""
        path = CELLS_DIR / f"{name}.toml"
        if not path.is_file():
            known = builtin_cell_names()
            raise NotFound(f"no built-in cell {name!r} (have: {', '.join(known)})", cell=name, known=known)
        return cls.load(path)

    @classmethod
    def from_toml_text(cls, text: str, base_dir: str | Path | None = None, source: str = "<cell>") -> Cell:
        """Parse and validate a cell from TOML text (``base_dir`` resolves relative robot paths)."""
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{source}: not valid TOML: {exc}", file=source) from exc
        _check_keys(doc, source)
        sec = {name: _Reader(doc.get(name, {}), name, source) for name in _SCHEMA}
        off = _Reader(doc.get("plate", {}).get("true_offset", {}), "plate.true_offset", source)
        robot, robot_source = _load_robot(sec["robot"], sec["tool"], sec["limits"], base_dir, source)
        c, ap = sec["cell"], sec["approach"]
        zone = ap.data.get("zone", "fine")
        if zone == "fine":
            zone_mm = 0.0
        elif isinstance(zone, (int, float)) and not isinstance(zone, bool) and 0 <= zone <= 200:
            zone_mm = float(zone)
        else:
            raise ConfigError(f"{source}: approach.zone: expected \"fine\" or 0..200 mm, got {zone!r}",
                              file=source, key="approach.zone", value=zone)
        home_deg = sec["home"].vec("joints_deg", n=robot.nq, lo=-720.0, hi=720.0)
        home = np.radians(home_deg)
        bad = np.flatnonzero((home < robot.lower_rad - 1e-9) | (home > robot.upper_rad + 1e-9))
        if len(bad):
            j = int(bad[0])
            raise ConfigError(f"{source}: home.joints_deg: {robot.joint_names[j]} = {home_deg[j]} deg is outside "
                              f"[{np.degrees(robot.lower_rad[j]):.1f}, {np.degrees(robot.upper_rad[j]):.1f}]",
                              file=source, key="home.joints_deg", joint=robot.joint_names[j])
        rb, tb, pl = sec["robot"], sec["table"], sec["plate"]
        hold = rb.text("redundancy_joint") if rb.has("redundancy_joint") else None
        try:
            robot.set_posture(home, hold)            # a redundant arm's IK holds this joint at its home value
        except ConfigError as exc:
            raise ConfigError(f"{source}: robot.redundancy_joint: {exc}", file=source,
                              key="robot.redundancy_joint", value=hold) from exc
        brand = rb.text("brand", default="").lower()
        if brand not in NATIVE_EXPORTS:
            known = sorted(b for b in NATIVE_EXPORTS if b)
            raise ConfigError(f"{source}: robot.brand: {brand!r} is not one of {', '.join(known)}",
                              file=source, key="robot.brand", value=brand)
        plate_T = _pose(pl.vec("xyz_mm", lo=-5000, hi=5000), pl.vec("rpy_deg", default=[0, 0, 0], lo=-360, hi=360))
        controller = rb.text("controller", default="")
        parse_robot(controller, f"{source}: robot.controller")          # a typed error now, not at connect time
        return cls(
            name=c.text("name"),
            description=c.text("description", default=""),
            robot=robot,
            robot_source=robot_source,
            brand=brand,
            controller=controller,
            deviation_bound_mm=rb.num("deviation_bound_mm", default=0.5, lo=0.01, hi=100.0),
            base_T=_pose(rb.vec("base_xyz_mm", default=[0, 0, 0], lo=-1e4, hi=1e4),
                         rb.vec("base_rpy_deg", default=[0, 0, 0], lo=-360, hi=360)),
            table_size_mm=tb.vec("size_mm", lo=1.0, hi=1e4),
            table_T=_pose(tb.vec("xyz_mm", lo=-5000, hi=5000), tb.vec("rpy_deg", default=[0, 0, 0], lo=-360, hi=360)),
            plate_size_mm=pl.vec("size_mm", lo=1.0, hi=2000.0),
            plate_T=plate_T,
            true_plate_T=plate_T @ _pose(off.vec("xyz_mm", default=[0, 0, 0], lo=-100, hi=100),
                                         off.vec("rpy_deg", default=[0, 0, 0], lo=-45, hi=45)),
            home_q_rad=home,
            approach_height_mm=ap.num("height_mm", lo=0.0, hi=1000.0),
            approach_speed_mm_s=ap.num("speed_mm_s", default=150.0, lo=1.0, hi=2000.0),
            approach_zone_mm=zone_mm,
            source_path=None if source == "<cell>" else source,
            raw=doc,
        )

    @property
    def native_export(self) -> str:
        """The export format the robot's own controller runs: RAPID (ABB), KRL (KUKA), URScript (UR), else CSV."""
        return NATIVE_EXPORTS[self.brand]

    def fingerprint(self) -> str:
        """A short digest of what makes the cell this cell: its robot, tool, table, plate, home and approach
        (not its description or the file it came from). A station's saved twin belongs to one cell."""
        d = self.to_dict()
        for key in ("description", "source_path", "controller", "deviation_bound_mm"):
            d.pop(key, None)
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]

    # Frames --------------------------------------------------------------
    def wobj_T(self) -> np.ndarray:
        """Nominal work object in the robot base frame: plate top-face corner (x min, y min)."""
        return self.plate_T @ self._corner()

    def true_wobj_T(self) -> np.ndarray:
        """The work object where the twin's plate really is (``true_plate_T``)."""
        return self.true_plate_T @ self._corner()

    def _corner(self) -> np.ndarray:
        sx, sy, sz = self.plate_size_mm
        return frames.make_T(np.eye(3), [-sx / 2.0, -sy / 2.0, sz])

    def home_tcp_T(self) -> np.ndarray:
        """TCP pose at the home joints (robot base frame)."""
        return self.robot.fk(self.home_q_rad)

    def to_dict(self) -> dict[str, Any]:
        """Plain summary for ``cell show`` (lists, floats and strings only)."""
        r = self.robot
        deg = lambda a: [round(float(v), 6) + 0.0 for v in np.degrees(a)]  # noqa: E731
        tool_xyz, tool_rpy = frames.T_to_xyzrpy(r.tool_T)
        return {
            "name": self.name,
            "description": self.description,
            "source_path": self.source_path,
            "brand": self.brand,
            "native_export": self.native_export,
            "controller": self.controller,
            "deviation_bound_mm": self.deviation_bound_mm,
            "robot": {"name": r.name, "source": self.robot_source, "flange_frame": r.flange_frame, "nq": r.nq,
                      "joint_names": list(r.joint_names), "closed_form_ik": r.closed_form is not None,
                      "ik_family": r.ik_family, "ik_parameters": r.family_choice.parameters(),
                      "redundancy_joint": None if r.hold_joint is None else r.joint_names[r.hold_joint],
                      "lower_deg": deg(r.lower_rad), "upper_deg": deg(r.upper_rad),
                      "vel_deg_s": deg(r.vel_limit_rad_s), "acc_deg_s2": deg(r.acc_limit_rad_s2),
                      "jerk_deg_s3": deg(r.jerk_limit_rad_s3), "base": _xyzrpy(self.base_T)},
            "tool": {"tcp_xyz_mm": [float(v) + 0.0 for v in tool_xyz],
                     "tcp_rpy_deg": [float(v) + 0.0 for v in tool_rpy],
                     **{k: float(v) for k, v in vars(r.tool).items()}},
            "table": {"size_mm": [float(v) for v in self.table_size_mm], **_xyzrpy(self.table_T)},
            "plate": {"size_mm": [float(v) for v in self.plate_size_mm], **_xyzrpy(self.plate_T),
                      "true": _xyzrpy(self.true_plate_T)},
            "wobj": _xyzrpy(self.wobj_T()),
            "home": {"joints_deg": deg(self.home_q_rad), "tcp": _xyzrpy(self.home_tcp_T())},
            "approach": {"height_mm": self.approach_height_mm, "speed_mm_s": self.approach_speed_mm_s,
                         "zone_mm": self.approach_zone_mm, "zone": "fine" if self.approach_zone_mm == 0 else
                         f"z{self.approach_zone_mm:g}"},
        }


def _load_robot(rb: _Reader, tl: _Reader, lim: _Reader, base_dir: str | Path | None,
                source: str) -> tuple[RobotModel, str]:
    """Build the RobotModel from ``[robot]``, ``[tool]`` and ``[limits]``."""
    tool_T = _pose(tl.vec("tcp_xyz_mm", lo=-1000, hi=1000), tl.vec("tcp_rpy_deg", default=[0, 0, 0], lo=-360, hi=360))
    defaults = ToolGeometry()
    tool = ToolGeometry(**{k: tl.num(k, default=getattr(defaults, k), lo=0.0 if k in ToolGeometry.OPTIONAL else 0.1,
                                     hi=1000.0) for k in vars(defaults)})
    if rb.has("urdf") == rb.has("example_robot_data"):
        raise ConfigError(f"{source}: [robot] needs exactly one of urdf / example_robot_data",
                          file=source, key="robot.urdf")
    if rb.has("urdf"):
        rel = Path(rb.text("urdf"))
        candidates = [rel] if rel.is_absolute() else [PACKAGE_DIR / rel] + ([Path(base_dir) / rel] if base_dir else [])
        path = next((c for c in candidates if c.is_file()), None)
        if path is None:
            raise ConfigError(f"{source}: robot.urdf: {rel} not found", file=source, key="robot.urdf", value=str(rel))
        robot = RobotModel.from_urdf(path, tool_T, rb.text("flange_frame", default="flange"),
                                     rb.text("name", default=path.stem), tool)
        robot_source = f"urdf:{rel}"
    else:
        name = rb.text("example_robot_data")
        try:
            robot = RobotModel.from_example_robot_data(name, tool_T, rb.data.get("flange_frame"), tool)
        except NotFound as exc:
            raise ConfigError(f"{source}: robot.example_robot_data: {exc}", file=source,
                              key="robot.example_robot_data", value=name) from exc
        robot_source = f"example_robot_data:{name}"
    over = {}
    for key, attr, lo in (("lower_deg", "lower_rad", -720.0), ("upper_deg", "upper_rad", -720.0),
                          ("vel_deg_s", "vel_limit_rad_s", 1e-3), ("acc_deg_s2", "acc_limit_rad_s2", 1e-3),
                          ("jerk_deg_s3", "jerk_limit_rad_s3", 1e-3)):
        if lim.has(key):
            over[attr] = np.radians(lim.vec(key, n=robot.nq, lo=lo, hi=1e7))
    for attr in ("lower_rad", "upper_rad"):
        if attr in over and np.any((over[attr] < robot.lower_rad - 1e-9) | (over[attr] > robot.upper_rad + 1e-9)):
            key = "limits." + attr.replace("_rad", "_deg")
            raise ConfigError(f"{source}: {key}: may only narrow the robot's own limits", file=source, key=key)
    if over:
        try:
            robot.with_limits(**over)
        except ValidationError as exc:
            raise ConfigError(f"{source}: [limits]: {exc}", file=source, key="limits") from exc
    return robot, robot_source
