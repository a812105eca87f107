"""Machine profiles: the kinematics and travel of a 5-axis machine (used by Makki 2010 §2.2.2).

A profile is one JSON document validated by :class:`MachineProfile`. Bundled profiles live in
``planning/orientations/profiles/<name>.json`` (package data); ``machine.profile`` in the plan configuration is
either such a name or a path to a JSON file of the same shape.

Angle conventions (degrees, right-hand rule about the positive machine axis; the exact formulas
are in :mod:`planning.orientations.kinematics`):

* ``tilt`` is the A axis (rotation about machine X) or the B axis (about machine Y);
* ``rotary`` is the C axis (about machine Z when the tilt is 0);
* with every axis at 0 the tool axis is part +Z.

Linear-axis geometry (translational travel, Makki 2010 §2.2.2, Fig. 4c; used by
:mod:`planning.visibility.travel`). All lengths in mm. Every field below is optional, so profiles written
before they existed stay valid and keep their behaviour:

* **Table frame**: origin at the table-top centre, on the C axis, with every rotary axis at 0;
  Z up (normal to the table top). A part-frame point ``p`` sits at ``p + placement_mm`` in it.
* **Machine frame**: fixed to the machine's rotary pivot; it coincides with the table frame when
  every rotary axis is at 0. The linear axes X/Y/Z position a **controlled point** in this frame:
  the spindle gauge point (tool axis on the gauge line) for table-table kinematics, the head's
  rotation centre (where the C and A/B axes meet, on the spindle axis) for head-head kinematics.
  Only the relative position of tool and table matters, so it does not matter which of them the
  real machine moves.
* ``x_limits_mm`` / ``y_limits_mm`` / ``z_limits_mm``: ``[min, max]`` machine coordinates of the
  controlled point, each spanning exactly the declared ``*_travel_mm`` (within
  :data:`LIMIT_SPAN_TOL_MM`). Defaults: X and Y centred on the table centre
  (``[-travel/2, +travel/2]``); Z from the lowest gauge-line height
  :data:`DEFAULT_MIN_GAUGE_HEIGHT_MM` (100 mm) above the table top with the rotary axes at 0 (plus
  ``head_pivot_length_mm`` for head-head, whose controlled point is the pivot) up over the travel.
* ``table_pivot_mm`` (table-table only): a point of the tilt (A or B) axis in the table frame;
  default ``[0, 0, 0]`` (the tilt axis passes through the table-top centre). A trunnion axis
  80 mm below the table top is ``[0, 0, -80]``. The C axis is the table frame's Z axis.
* ``head_pivot_length_mm`` (head-head only): distance along the tool axis from the spindle gauge
  line up to the head's rotation centre; default 0. The spindle axis passes through that centre.

Rotary speeds and the C register (simultaneous 5-axis, issue 33). Optional as well:

* ``tilt_feed_max_deg_min`` / ``rotary_feed_max_deg_min``: the fastest the tilt and the rotary axis
  turn during a feed move (deg/min; default :data:`DEFAULT_ROTARY_FEED_DEG_MIN`, 20 rev/min). The
  5-axis posts make each feed move last at least its turn over this; the verification reads the
  programs back and counts a feed move whose axes turn faster (``rotary_feed_excesses``).
* ``rotary_register_deg`` (continuous C only): the programs keep C within +- this (default
  :data:`DEFAULT_ROTARY_REGISTER_DEG`, ten turns); beyond it is a travel excursion. The planner and
  the posts turn C back before (between passes, where it is more than the register less two turns
  from 0).
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from planning.errors import ParameterError

__all__ = [
    "DEFAULT_MIN_GAUGE_HEIGHT_MM",
    "DEFAULT_ROTARY_FEED_DEG_MIN",
    "DEFAULT_ROTARY_REGISTER_DEG",
    "KINEMATICS",
    "LIMIT_SPAN_TOL_MM",
    "Kinematics",
    "MachineProfile",
    "available_profiles",
    "load_profile",
]

Kinematics = Literal["table_table_ac", "table_table_bc", "head_head_ac", "head_head_bc"]
KINEMATICS: tuple[str, ...] = ("table_table_ac", "table_table_bc", "head_head_ac", "head_head_bc")

#: Default lowest height of the spindle gauge line above the table top (rotary axes at 0, Z at the
#: bottom of its travel), mm; used when a profile gives no ``z_limits_mm``.
DEFAULT_MIN_GAUGE_HEIGHT_MM = 100.0

#: Default fastest turn of a rotary or tilt axis in a feed move, deg/min (20 rev/min).
DEFAULT_ROTARY_FEED_DEG_MIN = 7200.0

#: Default range of a continuous C in the programs, +- degrees (ten turns: within the soft limits controls
#: commonly give an unwrapped rotary axis, and the program's closing return to C0 stays under 30 s at 20 rev/min).
DEFAULT_ROTARY_REGISTER_DEG = 3600.0

#: Largest accepted difference between the span of ``*_limits_mm`` and ``*_travel_mm``, mm.
LIMIT_SPAN_TOL_MM = 1e-3

_Coord = Annotated[float, Field(ge=-100_000, le=100_000, allow_inf_nan=False)]
_Range = tuple[_Coord, _Coord]


class MachineProfile(BaseModel):
    """A 5-axis machine as the planner sees it: kinematic layout, rotary travel, linear travel.

    Rotary travel is used by machine visibility (Makki §2.2.2, Fig. 4b); the linear travels, their
    limits and the pivot geometry by the translational travel check (Fig. 4c,
    :mod:`planning.visibility.travel`). Frames and defaults: see the module docstring.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(
        ..., min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.\-]+$",
        description="Profile identifier; for a bundled profile, the file name without '.json'.")
    description: str = Field(
        "", max_length=2000, description="Free text: what the profile models and where its figures come from.")
    kinematics: Kinematics = Field(
        ...,
        description="Kinematic layout. 'table_table_ac' / 'table_table_bc': trunnion or cradle; the part sits "
                    "on a rotary C table carried by a tilting A (about machine X) or B (about machine Y) axis; "
                    "the spindle stays along machine +Z. 'head_head_ac' / 'head_head_bc': the part is fixed "
                    "(part frame = machine frame) and the spindle head swivels: C about machine Z carries "
                    "A (about the head's X) or B (about the head's Y).")
    tilt_min_deg: float = Field(
        ..., ge=-180, le=180,
        description="Lower travel limit of the tilt axis (A or B), degrees; 0 = tool axis along part +Z.")
    tilt_max_deg: float = Field(
        ..., ge=-180, le=180, description="Upper travel limit of the tilt axis (A or B), degrees.")
    rotary_continuous: bool = Field(
        False, description="True when the rotary (C) axis turns without limit; rotary_min_deg/max_deg must "
                           "then be null.")
    rotary_min_deg: float | None = Field(
        None, ge=-720, le=720,
        description="Lower travel limit of the rotary axis (C), degrees; required unless rotary_continuous.")
    rotary_max_deg: float | None = Field(
        None, ge=-720, le=720,
        description="Upper travel limit of the rotary axis (C), degrees; required unless rotary_continuous.")
    tilt_feed_max_deg_min: float | None = Field(
        None, gt=0, le=1_000_000, allow_inf_nan=False,
        description="Fastest the tilt axis (A or B) may turn during a feed move, deg/min. The simultaneous "
                    "5-axis posts give every feed move at least its tilt turn / this (LinuxCNC G93 inverse-time "
                    "F, ISO the tip feed lowered), and the verification counts a feed move that turns the tilt "
                    "faster as a rotary-speed offence. Default (null): 7200 deg/min (20 rev/min).")
    rotary_feed_max_deg_min: float | None = Field(
        None, gt=0, le=1_000_000, allow_inf_nan=False,
        description="Fastest the rotary axis (C) may turn during a feed move, deg/min; as "
                    "tilt_feed_max_deg_min. Default (null): 7200 deg/min (20 rev/min).")
    rotary_register_deg: float | None = Field(
        None, ge=360, le=100_000, allow_inf_nan=False,
        description="Continuous rotary axis only: the programs keep C within +-this, degrees (what the "
                    "control's soft limits of the unwrapped axis allow, and what the return to C0 at the end "
                    "has to unwind). The 5-axis posts turn C back to its twin in [-180, 180] in the air between "
                    "passes where it is more than the register less two turns from 0; a C beyond +-this is a travel excursion in the "
                    "verification. Default (null): 3600 (ten turns). Must be null when rotary_continuous is "
                    "false (the rotary travel limits apply).")
    x_travel_mm: float = Field(
        ..., gt=0, le=100_000,
        description="Travel of the X linear axis, mm (stroke, end to end). Used by the translational travel "
                    "check (Makki §2.2.2, Fig. 4c) with x_limits_mm; not used by rotary machine visibility.")
    y_travel_mm: float = Field(
        ..., gt=0, le=100_000, description="Travel of the Y linear axis, mm (stroke, end to end).")
    z_travel_mm: float = Field(
        ..., gt=0, le=100_000, description="Travel of the Z linear axis, mm (stroke, end to end).")
    x_limits_mm: _Range | None = Field(
        None,
        description="[min, max] machine X of the controlled point (table-table: spindle gauge point; "
                    "head-head: head rotation centre), mm, in the machine frame (origin at the table-top "
                    "centre with every rotary axis at 0, Z up; see the module docstring). Must span "
                    "x_travel_mm (within 0.001 mm). Default (null): [-x_travel_mm/2, +x_travel_mm/2], centred "
                    "on the table. Used by the translational travel check (Makki §2.2.2, Fig. 4c).")
    y_limits_mm: _Range | None = Field(
        None,
        description="[min, max] machine Y of the controlled point, mm; must span y_travel_mm. "
                    "Default (null): [-y_travel_mm/2, +y_travel_mm/2].")
    z_limits_mm: _Range | None = Field(
        None,
        description="[min, max] machine Z of the controlled point, mm (0 = table top with the rotary axes "
                    "at 0); must span z_travel_mm. Default (null): min = 100 mm (lowest gauge-line height "
                    "above the table top) plus head_pivot_length_mm for head-head, max = min + z_travel_mm.")
    table_pivot_mm: tuple[_Coord, _Coord, _Coord] | None = Field(
        None,
        description="Table-table only: [x, y, z] of a point of the tilt (A/B) axis in the table frame "
                    "(origin at the table-top centre on the C axis, Z up, rotary axes at 0), mm; the "
                    "component along the tilt axis is irrelevant. E.g. [0, 0, -80]: tilt axis 80 mm below "
                    "the table top. Default (null): [0, 0, 0], the tilt axis passes through the table-top "
                    "centre. Must be null for head-head kinematics.")
    head_pivot_length_mm: float | None = Field(
        None, ge=0, le=10_000, allow_inf_nan=False,
        description="Head-head only: distance along the tool axis from the spindle gauge line up to the "
                    "head's rotation centre (where the C and A/B axes meet, on the spindle axis), mm. "
                    "Default (null): 0. Must be null for table-table kinematics.")

    @model_validator(mode="after")
    def _consistent(self) -> MachineProfile:
        if not self.tilt_min_deg < self.tilt_max_deg:
            raise ValueError(f"tilt_min_deg ({self.tilt_min_deg:g}) must be below tilt_max_deg "
                             f"({self.tilt_max_deg:g})")
        if self.rotary_continuous:
            if self.rotary_min_deg is not None or self.rotary_max_deg is not None:
                raise ValueError("rotary_continuous is true: rotary_min_deg and rotary_max_deg must be null")
        else:
            if self.rotary_register_deg is not None:
                raise ValueError("rotary_register_deg applies to a continuous rotary axis only (rotary_continuous "
                                 "is false: rotary_min_deg / rotary_max_deg bound C); leave it null")
            if self.rotary_min_deg is None or self.rotary_max_deg is None:
                raise ValueError("rotary_min_deg and rotary_max_deg are required when rotary_continuous is false")
            if not self.rotary_min_deg < self.rotary_max_deg:
                raise ValueError(f"rotary_min_deg ({self.rotary_min_deg:g}) must be below rotary_max_deg "
                                 f"({self.rotary_max_deg:g})")
        for ax in ("x", "y", "z"):
            lim = getattr(self, f"{ax}_limits_mm")
            if lim is None:
                continue
            lo, hi = lim
            travel = getattr(self, f"{ax}_travel_mm")
            if not lo < hi:
                raise ValueError(f"{ax}_limits_mm = [{lo:g}, {hi:g}]: the minimum must be below the maximum")
            if abs((hi - lo) - travel) > LIMIT_SPAN_TOL_MM:
                raise ValueError(f"{ax}_limits_mm = [{lo:g}, {hi:g}] spans {hi - lo:g} mm but {ax}_travel_mm is "
                                 f"{travel:g} mm; the limits must span exactly the travel")
        if self.table_pivot_mm is not None and not self.is_table_table:
            raise ValueError(f"table_pivot_mm applies to table-table kinematics only (kinematics is "
                             f"{self.kinematics!r}); leave it null")
        if self.head_pivot_length_mm is not None and self.is_table_table:
            raise ValueError(f"head_pivot_length_mm applies to head-head kinematics only (kinematics is "
                             f"{self.kinematics!r}); leave it null")
        return self

    @property
    def is_table_table(self) -> bool:
        """True for table-table kinematics (the part turns, the spindle stays along machine +Z)."""
        return self.kinematics.startswith("table_table")

    @property
    def axis_names(self) -> tuple[str, str]:
        """Machine names of the (tilt, rotary) axes, e.g. ``('B', 'C')``."""
        return (self.kinematics[-2].upper(), self.kinematics[-1].upper())

    @property
    def feed_limits_deg_min(self) -> tuple[float, float]:
        """``(tilt, rotary)``: the fastest turns in a feed move, deg/min (``tilt_feed_max_deg_min``,
        ``rotary_feed_max_deg_min``; default :data:`DEFAULT_ROTARY_FEED_DEG_MIN` each)."""
        return tuple(float(DEFAULT_ROTARY_FEED_DEG_MIN if v is None else v)
                     for v in (self.tilt_feed_max_deg_min, self.rotary_feed_max_deg_min))

    @property
    def rotary_limits_deg(self) -> tuple[float, float]:
        """``(min, max)`` of the C a program may command, degrees: the rotary travel, or for a continuous
        axis +-``rotary_register_deg`` (default :data:`DEFAULT_ROTARY_REGISTER_DEG`)."""
        if not self.rotary_continuous:
            return (float(self.rotary_min_deg), float(self.rotary_max_deg))
        r = float(DEFAULT_ROTARY_REGISTER_DEG if self.rotary_register_deg is None else self.rotary_register_deg)
        return (-r, r)

    @property
    def pivot_length_mm(self) -> float:
        """Head-head: gauge line to head rotation centre, mm (``head_pivot_length_mm``, default 0);
        0 for table-table."""
        return float(self.head_pivot_length_mm or 0.0)

    @property
    def pivot_mm(self) -> tuple[float, float, float]:
        """Table-table: a point of the tilt axis in the table frame, mm (``table_pivot_mm``, default the
        origin); the origin for head-head."""
        if self.table_pivot_mm is None:
            return (0.0, 0.0, 0.0)
        x, y, z = self.table_pivot_mm
        return (float(x), float(y), float(z))

    @property
    def linear_limits_mm(self) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
        """``((xmin, xmax), (ymin, ymax), (zmin, zmax))``: machine-frame limits of the controlled point,
        mm, with the documented defaults applied (Makki §2.2.2, Fig. 4c)."""
        out = []
        for ax in ("x", "y", "z"):
            lim = getattr(self, f"{ax}_limits_mm")
            travel = float(getattr(self, f"{ax}_travel_mm"))
            if lim is not None:
                out.append((float(lim[0]), float(lim[1])))
            elif ax == "z":
                lo = DEFAULT_MIN_GAUGE_HEIGHT_MM + self.pivot_length_mm
                out.append((lo, lo + travel))
            else:
                out.append((-0.5 * travel, 0.5 * travel))
        return (out[0], out[1], out[2])


def _profiles_dir():
    return resources.files("planning.orientations").joinpath("profiles")


def available_profiles() -> list[str]:
    """Names of the bundled machine profiles (``planning/orientations/profiles/*.json``), sorted."""
    d = _profiles_dir()
    return sorted(p.name[:-5] for p in d.iterdir() if p.name.endswith(".json"))


def _validate(data, source: str) -> MachineProfile:
    if not isinstance(data, dict):
        raise ParameterError(f"machine profile {source}: the file must hold a JSON object")
    try:
        return MachineProfile.model_validate(data)
    except ValidationError as exc:
        problems = []
        for e in exc.errors():
            path = ".".join(str(p) for p in e.get("loc", ())) or "(profile)"
            if e.get("type") == "extra_forbidden":
                problems.append(f"{path}: unknown field")
            elif e.get("type") == "missing":
                problems.append(f"{path}: missing")
            else:
                problems.append(f"{path} = {e.get('input')!r}: {e.get('msg')}")
        raise ParameterError(f"machine profile {source} is invalid: " + "; ".join(problems),
                             parameter="machine.profile", problems=problems) from None


def load_profile(name_or_path: str | Path | MachineProfile) -> MachineProfile:
    """Load a machine profile (Makki §2.2.2 machine model) by bundled name or from a JSON file path.

    A string equal to a bundled profile name (see :func:`available_profiles`) loads that profile;
    otherwise it is read as a path to a JSON file. A :class:`MachineProfile` is returned unchanged.
    Raises :class:`ParameterError` for an unknown name (listing the available names), an unreadable
    file, invalid JSON or invalid fields.
    """
    if isinstance(name_or_path, MachineProfile):
        return name_or_path
    if not isinstance(name_or_path, (str, Path)):
        raise ParameterError(f"machine.profile = {name_or_path!r}: expected a profile name or a file path",
                             parameter="machine.profile")
    names = available_profiles()
    key = str(name_or_path)
    if isinstance(name_or_path, str) and key in names:
        text = _profiles_dir().joinpath(key + ".json").read_text(encoding="utf-8")
        source = f"'{key}'"
    else:
        path = Path(name_or_path)
        if not path.is_file():
            raise ParameterError(
                f"machine.profile = {key!r}: no bundled profile of that name and no such file; "
                f"available profiles: {', '.join(names)}",
                parameter="machine.profile", value=key, allowed=names)
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ParameterError(f"machine.profile = {key!r}: cannot read the file ({exc})",
                                 parameter="machine.profile", value=key) from None
        source = f"file {key!r}"
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ParameterError(f"machine profile {source} is not valid JSON: {exc}",
                             parameter="machine.profile", value=key) from None
    return _validate(data, source)
