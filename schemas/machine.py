"""Machine profiles: the kinematics and travel of a 5-axis machine (used by Makki 2010 §2.2.2).

A profile is one JSON document validated by :class:`MachineProfile`. Bundled profiles live in
``planning/profiles/<name>.json`` (package data); ``machine.profile`` in the plan configuration is
either such a name or a path to a JSON file of the same shape.

Angle conventions (degrees, right-hand rule about the positive machine axis; the exact formulas
are in :mod:`planning.machine`):

* ``tilt`` is the A axis (rotation about machine X) or the B axis (about machine Y);
* ``rotary`` is the C axis (about machine Z when the tilt is 0);
* with every axis at 0 the tool axis is part +Z.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from planning.errors import ParameterError

__all__ = ["Kinematics", "KINEMATICS", "MachineProfile", "available_profiles", "load_profile"]

Kinematics = Literal["table_table_ac", "table_table_bc", "head_head_ac", "head_head_bc"]
KINEMATICS: tuple[str, ...] = ("table_table_ac", "table_table_bc", "head_head_ac", "head_head_bc")


class MachineProfile(BaseModel):
    """A 5-axis machine as the planner sees it: kinematic layout, rotary travel, linear travel.

    Only rotary travel is used by machine visibility today (Makki §2.2.2, Fig. 4b); the linear
    travels are declared for the collision / translational-travel check (Fig. 4c).
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
    x_travel_mm: float = Field(
        ..., gt=0, le=100_000,
        description="Travel of the X linear axis, mm (stroke, end to end). Declared for the translational "
                    "travel check (Makki §2.2.2, Fig. 4c); not used by rotary machine visibility.")
    y_travel_mm: float = Field(
        ..., gt=0, le=100_000, description="Travel of the Y linear axis, mm (stroke, end to end).")
    z_travel_mm: float = Field(
        ..., gt=0, le=100_000, description="Travel of the Z linear axis, mm (stroke, end to end).")

    @model_validator(mode="after")
    def _consistent(self) -> "MachineProfile":
        if not self.tilt_min_deg < self.tilt_max_deg:
            raise ValueError(f"tilt_min_deg ({self.tilt_min_deg:g}) must be below tilt_max_deg "
                             f"({self.tilt_max_deg:g})")
        if self.rotary_continuous:
            if self.rotary_min_deg is not None or self.rotary_max_deg is not None:
                raise ValueError("rotary_continuous is true: rotary_min_deg and rotary_max_deg must be null")
        else:
            if self.rotary_min_deg is None or self.rotary_max_deg is None:
                raise ValueError("rotary_min_deg and rotary_max_deg are required when rotary_continuous is false")
            if not self.rotary_min_deg < self.rotary_max_deg:
                raise ValueError(f"rotary_min_deg ({self.rotary_min_deg:g}) must be below rotary_max_deg "
                                 f"({self.rotary_max_deg:g})")
        return self

    @property
    def is_table_table(self) -> bool:
        """True for table-table kinematics (the part turns, the spindle stays along machine +Z)."""
        return self.kinematics.startswith("table_table")

    @property
    def axis_names(self) -> tuple[str, str]:
        """Machine names of the (tilt, rotary) axes, e.g. ``('B', 'C')``."""
        return (self.kinematics[-2].upper(), self.kinematics[-1].upper())


def _profiles_dir():
    return resources.files("planning").joinpath("profiles")


def available_profiles() -> list[str]:
    """Names of the bundled machine profiles (``planning/profiles/*.json``), sorted."""
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


def load_profile(name_or_path: "str | Path | MachineProfile") -> MachineProfile:
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
