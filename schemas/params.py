"""The plan configuration: every parameter's name, unit, default and range, declared once.

The CLI (``--config FILE``, ``--set path=value``), the API (job ``parameters``) and the docs all
derive from these models. Names follow docs/design.md ("Parameter names"); units are in the names
(``_mm``, ``_deg``, ``_s``). Unknown keys are rejected, so a typo never silently falls back to a
default.
"""

from __future__ import annotations

import difflib
import json
import typing
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from planning.errors import ParameterError

Vec3 = tuple[float, float, float]

PAPER_DIRECTIONS: list[Vec3] = [(0, 0, 1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class ReliefParams(_Strict):
    """An image read as a relief (Sood 2015 ch. 3): one point per pixel, intensity mapped to height."""

    size_mm: float = Field(
        100.0, gt=0, le=10_000,
        description="Length of the image's longer side on the part, in mm (aspect kept; pixel spacing = "
                    "size_mm / (pixels along the longer side - 1)).")
    z_min_mm: float = Field(
        0.0, ge=-10_000, le=10_000, description="Height of the lowest relief point, in mm.")
    z_max_mm: float = Field(
        10.0, ge=-10_000, le=10_000,
        description="Height of the highest relief point, in mm; the image's intensity range is mapped "
                    "linearly onto [z_min_mm, z_max_mm] (Sood eq. 3.3).")
    dark: Literal["low", "high"] = Field(
        "low", description="'low': dark pixels are low and bright ones high (Sood's default); 'high': the "
                           "reverse (dark engraved lines standing up).")
    blur: Literal[0, 3, 5] = Field(
        0, description="Gaussian blur before the mapping, kernel size in pixels: 0 (none), 3 (3x3) or 5 "
                       "(5x5); smooths abrupt jumps between bright and dark pixels (Sood §3.2.2).")
    max_pixels: int = Field(
        524_288, ge=4, le=50_000_000,
        description="Most pixels an image is planned on (one point and two triangles each), checked from the "
                    "image header before it is decoded. A larger image is scaled down to fit (area averaging, "
                    "aspect kept; the plan's warnings name the decoded size) if it has at most 16 x max_pixels "
                    "pixels, and refused beyond that. The default, 524,288 (e.g. 724 x 724, a 0.14 mm pitch on a "
                    "100 mm relief), keeps a relief job with the other defaults within 1.5 GB of memory (measured: "
                    "a 1024 x 1024 height map planned at 724 x 724 peaked at 1.42 GB; planned whole, 2.68 GB).")
    fill_missing: bool = Field(
        False, description="A float (TIFF) image whose pixels are NaN or infinite (no data) is refused by default, "
                           "since it would flatten or shift the whole relief; true fills each such pixel from its "
                           "nearest valid pixel and the plan's warnings say how many were filled.")

    @model_validator(mode="after")
    def _z_range(self) -> "ReliefParams":
        if not self.z_max_mm > self.z_min_mm:
            raise ValueError(f"z_max_mm ({self.z_max_mm:g}) must be above z_min_mm ({self.z_min_mm:g}): the "
                             "brightest and darkest pixels need different heights")
        return self


class InputParams(_Strict):
    """How the submitted cloud is read and what is accepted."""

    units: Literal["mm", "m", "in"] = Field(
        "mm", description="Unit of the coordinates in the file; everything is converted to millimetres.")
    max_points: int = Field(
        20_000_000, ge=1, le=200_000_000,
        description="Largest accepted cloud, in points (checked from the file header before reading).")
    max_extent_mm: float = Field(
        5_000.0, gt=0, le=100_000,
        description="Largest accepted bounding-box side, in mm (catches files written in the wrong unit).")
    min_points: int = Field(
        10, ge=4, le=1_000_000, description="Smallest accepted cloud, in points.")
    max_faces: int = Field(
        10_000_000, ge=1, le=200_000_000,
        description="Largest accepted mesh, in triangles after polygons are split (STL, OBJ, PLY faces, E57 grids; "
                    "checked from the header or the file size before the faces are read).")
    relief: ReliefParams = Field(
        default_factory=ReliefParams,
        description="How an image (PNG, JPEG, BMP, TIFF) is read as a relief; ignored for point clouds and "
                    "meshes.")
    accept_small_part: bool = Field(
        False, description="Plan a part whose largest side is under min_part_tool_diameters tool diameters, or "
                           "on which sphere throwing finds almost no normals; by default such a cloud is refused "
                           "as a likely unit mistake (a scan in metres read as mm).")
    mesh_sample_mm: float = Field(
        0.5, gt=0, le=100, description="A mesh (STL, OBJ, PLY with faces, scanner grid, relief) is planned on its "
                                       "vertices plus points laid on its edges and facets at most this far apart, "
                                       "mm; the finishing ball rests on the triangles themselves.")
    mesh_max_points: int = Field(
        2_000_000, ge=1, le=50_000_000, description="At most this many points on a mesh's facets (the spacing is "
                                                    "widened to fit; plan.json input gives the spacing used).")
    min_part_tool_diameters: float = Field(
        2.0, ge=0, le=1000, description="The smallest accepted largest side of the part's bounding box, in tool "
                                        "diameters (checked unless accept_small_part).")


class NormalsParams(_Strict):
    """Normal estimation by sphere throwing (Makki 2010 §2.1, eq. 2.1) or taken from the file."""

    method: Literal["sphere_throwing", "input", "facets"] = Field(
        "sphere_throwing",
        description="'sphere_throwing' estimates outward normals; 'input' uses the normals stored in the file "
                    "(PLY nx ny nz, PCD normal_x..), every point then being a sample; 'facets' (meshes only) takes "
                    "them from the triangles, wound consistently outward: at a vertex the normalised mean of its "
                    "facets' normals (Chui 2008 eq. 8), on a facet its normal, on an edge the mean of its two.")
    sphere_diameter_mm: float = Field(
        7.0, gt=0, le=500, description="Diameter of the thrown sphere, in mm (paper: 7 mm on the femur).")
    grid_spacing_mm: float | None = Field(
        None, gt=0, le=100,
        description="Spacing of the grid of throwing lines, in mm; null derives it from the point density "
                    "(the value used is reported in plan.json).")
    refine: bool = Field(
        False,
        description="Refit each sphere-throwing normal by a least-squares plane through the cloud's points within "
                    "the candidate cell (2 grid spacings), keeping throwing's sampled points and outward side "
                    "(planning.normals.refine). Off: the paper's contact normals. On sparse scans (range scans, "
                    "0.3 x 0.6 mm pitches) it cuts the error several times: bench/bench_normals_range.py.")
    directions: list[Vec3] = Field(
        default_factory=lambda: list(PAPER_DIRECTIONS), min_length=1, max_length=64,
        description="Throwing directions (part frame, need not be unit); the sphere comes from +direction. "
                    "Default: the paper's five, +Z +X -X +Y -Y.")

    @field_validator("directions")
    @classmethod
    def _nonzero(cls, v: list[Vec3]) -> list[Vec3]:
        for i, d in enumerate(v):
            if sum(c * c for c in d) < 1e-18:
                raise ValueError(f"direction {i} is the zero vector")
        return v


class OrientationsParams(_Strict):
    """Candidate tool axes on the discretized Gaussian sphere (Makki §2.2.1)."""

    sampling: Literal["phi_theta", "uniform"] = Field(
        "phi_theta", description="'phi_theta': the paper's grid of polar angle phi and azimuth theta; "
                                 "'uniform': a near-uniform sampling at resolution_deg.")
    phi_step_deg: float = Field(10.0, gt=0, le=180, description="Polar-angle step (from +Z), in degrees.")
    theta_step_deg: float = Field(30.0, gt=0, le=360, description="Azimuth step (from +X towards +Y), in degrees.")
    resolution_deg: float = Field(
        10.0, ge=1, le=90, description="Angular resolution of the 'uniform' sampling, in degrees.")


class MachineParams(_Strict):
    """The machine the part is machined on (rotary travel gives the machine visibility, Makki §2.2.2)."""

    profile: str = Field(
        "compact_trunnion_bc", min_length=1, max_length=200,
        description="A bundled profile name (see `scanmill profiles`) or a path to a profile JSON file.")


class HolderElement(_Strict):
    """One coaxial piece of the tool holder (collet nut, body, flange), listed from the holder face
    towards the spindle."""

    diameter_mm: float = Field(..., gt=0, le=1000, description="Diameter at its lower end (tool side), mm.")
    length_mm: float | None = Field(
        ..., gt=0, le=5000,
        description="Length along the tool axis, mm; null (last element only) = unbounded towards the spindle.")
    top_diameter_mm: float | None = Field(
        None, gt=0, le=1000,
        description="Diameter at its upper end for a cone, mm; null = a cylinder. Cones are checked as "
                    "stacked cylinders that contain them (at most 0.1 mm larger in radius).")


def _default_holder() -> list["HolderElement"]:
    return [HolderElement(diameter_mm=25.0, length_mm=45.0), HolderElement(diameter_mm=50.0, length_mm=40.0)]


class ToolParams(_Strict):
    """The cutter and its holder (Makki §2.2.4 models both as cylinders along the tool axis)."""

    type: Literal["ball"] = Field("ball", description="Cutter type: ball-end mill.")
    diameter_mm: float = Field(6.0, gt=0, le=100, description="Cutter diameter, in mm.")
    flute_length_mm: float = Field(
        12.0, gt=0, le=1000, description="Cutting length measured from the tool tip, mm (at least the ball radius).")
    stickout_mm: float = Field(
        30.0, gt=0, le=2000, description="Length from the tool tip to the holder face, mm (at least the flute length).")
    shank_diameter_mm: float | None = Field(
        None, gt=0, le=100, description="Diameter between the flutes and the holder, mm; null = the cutter diameter.")
    holder: list[HolderElement] = Field(
        default_factory=_default_holder, max_length=20,
        description="Holder pieces from the holder face up (default: a 25 mm x 45 mm collet nut and a "
                    "50 mm x 40 mm flange). Nothing above the last piece is checked unless its length is null.")
    gauge_length_mm: float | None = Field(
        None, gt=0, le=5000,
        description="Tool tip to spindle gauge line, mm (used by the travel check); null = stick-out plus "
                    "the holder lengths.")

    @model_validator(mode="after")
    def _assembly(self) -> "ToolParams":
        self.assembly()
        return self

    def assembly(self):
        """The :class:`planning.geometry.tool.ToolAssembly` these parameters describe."""
        from planning.geometry.tool import ball_tool
        try:
            return ball_tool(
                self.diameter_mm / 2.0, flute_length_mm=self.flute_length_mm, stickout_mm=self.stickout_mm,
                shank_radius_mm=None if self.shank_diameter_mm is None else self.shank_diameter_mm / 2.0,
                holder=[(h.diameter_mm / 2.0, h.length_mm,
                         None if h.top_diameter_mm is None else h.top_diameter_mm / 2.0) for h in self.holder],
                gauge_length_mm=self.gauge_length_mm)
        except ParameterError as exc:
            raise ValueError(str(exc)) from None


class VisibilityParams(_Strict):
    """Which axes may machine a point (Makki §2.2.3 tool visibility, §2.2.4 global visibility)."""

    cone_deg: tuple[float, float] = Field(
        (10.0, 80.0),
        description="[v1, v2]: admissible angle between tool axis and normal, in degrees, 0 <= v1 < v2 <= 90. "
                    "v1 avoids cutting with the tool tip (zero cutting speed), v2 avoids near-vertical "
                    "cutting (high scallops). Paper: [10, 80] and [10, 60].")
    global_: bool = Field(
        True, alias="global",
        description="Global visibility (Makki §2.2.4): drop the (point, axis) pairs where the cutter, shank or "
                    "holder would hit another point of the cloud, a fixture or the table.")
    travel: bool = Field(
        True, description="Translational travel (Makki Fig. 4c): drop the pairs whose machine X/Y/Z position "
                          "lies outside the profile's linear limits, with the part placed as in `fixtures`.")
    obstacles: Literal["all", "sampled"] = Field(
        "all",
        description="Cloud points the collision test checks: 'all' = every input point (exact for the scan; time "
                    "grows with its size); 'sampled' = only the points that got a normal (one per throwing-grid "
                    "square: 5-8x faster on the femur-like scan, but a tool passing between samples is missed - on "
                    "the femur-like case 0.02 % of the pairs, 0.6 % of the collisions).")

    @field_validator("cone_deg")
    @classmethod
    def _cone(cls, v: tuple[float, float]) -> tuple[float, float]:
        v1, v2 = v
        if not (0.0 <= v1 < v2 <= 90.0):
            raise ValueError(f"need 0 <= v1 < v2 <= 90 degrees, got [{v1}, {v2}]")
        return v


class BoxFixtureItem(_Strict):
    """An axis-aligned box in part coordinates (vise jaw, clamp, riser), mm."""

    type: Literal["box"] = "box"
    name: str = Field("box", max_length=100, description="Name used in reports.")
    min_mm: Vec3 = Field(..., description="Lower corner (x, y, z), mm.")
    max_mm: Vec3 = Field(..., description="Upper corner (x, y, z), mm.")

    @model_validator(mode="after")
    def _ordered(self) -> "BoxFixtureItem":
        if any(a >= b for a, b in zip(self.min_mm, self.max_mm)):
            raise ValueError(f"box min_mm {list(self.min_mm)} must be below max_mm {list(self.max_mm)}")
        return self


class CylinderFixtureItem(_Strict):
    """A solid cylinder in part coordinates (chuck, round riser, clamp bolt), mm."""

    type: Literal["cylinder"] = "cylinder"
    name: str = Field("cylinder", max_length=100, description="Name used in reports.")
    base_mm: Vec3 = Field(..., description="Centre of the base disc (x, y, z), mm.")
    axis: Vec3 = Field((0.0, 0.0, 1.0), description="Direction from the base to the top (need not be unit).")
    radius_mm: float = Field(..., gt=0, le=10_000, description="Radius, mm.")
    height_mm: float = Field(..., gt=0, le=10_000, description="Height along the axis, mm.")

    @field_validator("axis")
    @classmethod
    def _axis(cls, v: Vec3) -> Vec3:
        if sum(c * c for c in v) < 1e-18:
            raise ValueError("the cylinder axis is the zero vector")
        return v


class MeshFixtureItem(_Strict):
    """A fixture from a triangle mesh file (STL, OBJ, PLY), in part coordinates. CLI only: the
    service does not read paths on its own disk."""

    type: Literal["mesh"] = "mesh"
    name: str = Field("mesh", max_length=100, description="Name used in reports.")
    path: str = Field(..., min_length=1, max_length=1000, description="Mesh file (.stl, .obj, .ply).")
    units: Literal["mm", "m", "in"] = Field("mm", description="Unit of the mesh coordinates.")


class PointsFixtureItem(_Strict):
    """A forbidden region given as points (Makki's way of adding fixtures): the tool and holder must
    not contain any of them, exactly like the cloud's own points."""

    type: Literal["points"] = "points"
    name: str = Field("points", max_length=100, description="Name used in reports.")
    points_mm: list[Vec3] = Field(..., min_length=1, max_length=1_000_000, description="Points (x, y, z), mm.")


FixtureItem = Annotated[Union[BoxFixtureItem, CylinderFixtureItem, MeshFixtureItem, PointsFixtureItem],
                        Field(discriminator="type")]


class FixturesParams(_Strict):
    """Where the part sits on the machine and what holds it (Makki §2.2.4 fixtures, Fig. 4c placement)."""

    placement_mm: Vec3 | None = Field(
        None, description="Position of the part-frame origin in the table frame (origin at the table-top centre "
                          "on the C axis, Z up), mm; null = the part centred over the table with its lowest "
                          "point fixture_height_mm above the table top.")
    fixture_height_mm: float = Field(
        50.0, ge=0, le=5000, description="Height of the part's lowest point above the table top when "
                                         "placement_mm is null, mm.")
    table: bool = Field(True, description="Treat the machine table (everything below its top) as an obstacle.")
    items: list[FixtureItem] = Field(
        default_factory=list, max_length=100, description="Fixtures in part coordinates: boxes, cylinders, meshes, "
                                                          "forbidden points.")
    placement: Literal["as_scanned", "auto"] = Field(
        "as_scanned",
        description="How the part is put on the table. 'as_scanned': as it lies in the scan's frame (z up). 'auto': "
                    "try it as scanned, resting on each of its most stable convex-hull faces and with each principal "
                    "axis up and down, and plan the placement that reaches setups.coverage with the fewest set-ups, "
                    "then the least overlap, then the lowest part (docs/design.md 'Placement'); plan.json placement "
                    "gives the rotation and translation applied to the scan, placed.ply the placed cloud. With "
                    "'auto', placement_mm must be null and items are in the placed frame.")

    @model_validator(mode="after")
    def _auto_placement(self) -> "FixturesParams":
        if self.placement == "auto" and self.placement_mm is not None:
            raise ValueError("placement 'auto' chooses how the part sits on the table: leave placement_mm null "
                             "(fixture_height_mm sets the riser)")
        return self


class IndexZone(_Strict):
    """A functional zone given as indices into the submitted cloud (0-based)."""

    type: Literal["indices"] = "indices"
    indices: list[Annotated[int, Field(ge=0)]] = Field(..., min_length=1, description="Input point indices.")


class BoxZone(_Strict):
    """A functional zone given as an axis-aligned box in part coordinates (mm)."""

    type: Literal["box"] = "box"
    min_mm: Vec3 = Field(..., description="Lower corner (x, y, z), mm.")
    max_mm: Vec3 = Field(..., description="Upper corner (x, y, z), mm.")

    @model_validator(mode="after")
    def _ordered(self) -> "BoxZone":
        if any(a > b for a, b in zip(self.min_mm, self.max_mm)):
            raise ValueError(f"box min_mm {list(self.min_mm)} must not exceed max_mm {list(self.max_mm)}")
        return self


class SphereZone(_Strict):
    """A functional zone given as a ball in part coordinates (mm)."""

    type: Literal["sphere"] = "sphere"
    center_mm: Vec3 = Field(..., description="Centre (x, y, z), mm.")
    radius_mm: float = Field(..., gt=0, description="Radius, mm.")


FunctionalZone = Annotated[Union[IndexZone, BoxZone, SphereZone], Field(discriminator="type")]


class SetupsParams(_Strict):
    """Choice of the fixed orientations (Makki §3): fewest set-ups, then least overlap."""

    coverage: float = Field(
        0.95, gt=0, le=1, description="P_a: fraction of the sampled points the set-ups must see together.")
    max_setups: int = Field(5, ge=1, le=12, description="n_pmax: most set-ups allowed.")
    min_points: int = Field(
        1, ge=1, description="Orientations seeing fewer sampled points than this are dropped before the search.")
    functional_zones: list[FunctionalZone] = Field(
        default_factory=list, description="Zones where no point may be seen by two chosen set-ups (no overlap).")
    solver: Literal["auto", "branch_and_bound", "cpsat"] = Field(
        "auto", description="'auto' = exact branch and bound; 'cpsat' = OR-Tools CP-SAT model (slow at scale).")
    time_limit_s: float = Field(
        60.0, gt=0, le=86_400, description="Time limit of the exact search, in seconds; the gap is reported if hit.")


class AreasParams(_Strict):
    """Assignment of every point to one chosen set-up (Makki §3.1), as contiguous regions with short
    seams: a labelling energy over the points' neighbourhood graph minimised by a graph cut
    (planning/areas/labelling.py; docs/design.md stage 6)."""

    method: Literal["graphcut", "per_point"] = Field(
        "graphcut", description="'graphcut': minimise comfort plus seam length (alpha-expansion); 'per_point': each "
                                "point its most comfortable set-up alone, leftovers to the nearest labelled point "
                                "(the former rule, speckled; kept for comparison).")
    neighbours: int = Field(
        8, ge=3, le=32, description="k of the symmetrised k-nearest-neighbour graph of the sampled points.")
    smoothness_mm: float = Field(
        5.0, ge=0, le=10_000,
        description="lambda, mm: a seam 1 mm long costs as much as lambda mm^2 of surface machined at the edge of "
                    "the tool cone instead of its middle. 0 = the per-point rule.")
    sharp_edge_deg: float = Field(
        30.0, ge=0, le=180, description="Neighbours whose normals differ by more than this (degrees) lie across a "
                                        "sharp edge of the part, where a seam shows least.")
    sharp_edge_weight: float = Field(
        0.25, ge=0, le=1, description="Factor on the cost of a seam across a sharp edge (1 = no preference).")
    min_region_mm2: float = Field(
        25.0, ge=0, le=1e7, description="Regions smaller than this (mm^2) join a larger neighbouring area that sees "
                                        "all their points; 0 keeps every region.")


class StockParams(_Strict):
    """The blank the programs cut, in part coordinates (mm), for the simulation (planning/simulate/)."""

    type: Literal["box", "cylinder", "mesh"] = Field(
        "box", description="'box': the part's bounding box grown by margin_mm, or min_mm/max_mm when given; "
                           "'cylinder': the smallest cylinder about axis through the box's centre, grown by margin_mm; "
                           "'mesh': the real blank, a closed STL/OBJ/PLY mesh at path in part coordinates (CLI only).")
    path: str | None = Field(None, min_length=1, max_length=1000,
                             description="Mesh file of the blank for type 'mesh' (relative to the configuration's folder).")
    units: Literal["mm", "m", "in"] = Field("mm", description="Unit of the blank mesh's coordinates.")
    margin_mm: float = Field(2.0, ge=0, le=1000, description="Stock beyond the part's bounding box on every side, mm.")
    min_mm: Vec3 | None = Field(None, description="Lower corner of an explicit box stock (x, y, z), mm.")
    max_mm: Vec3 | None = Field(None, description="Upper corner of an explicit box stock (x, y, z), mm.")
    axis: Literal["x", "y", "z"] = Field("z", description="Axis of a cylinder stock (part frame).")

    @model_validator(mode="after")
    def _corners(self):
        if (self.min_mm is None) != (self.max_mm is None):
            raise ValueError("stock.min_mm and stock.max_mm go together")
        if self.min_mm is not None and not all(a < b for a, b in zip(self.min_mm, self.max_mm)):
            raise ValueError("stock.min_mm must be below stock.max_mm on every axis")
        if (self.type == "mesh") != (self.path is not None):
            raise ValueError("stock.path is required with stock.type 'mesh' and only then")
        return self


class SimulateParams(_Strict):
    """Running the posted programs on a tri-dexel stock model (issue 15; docs/programs.md, verification)."""

    enabled: bool = Field(True, description="Simulate every program and put the verdict into the plan.")
    resolution_mm: float = Field(
        1.0, ge=0.05, le=10, description="Spacing of the dexel rays, mm: finer finds thinner contacts and measures the "
                                         "deviation closer (bound 3/4 r^2 / R), at a cost of time and memory growing "
                                         "as about 1/r^2 (femur-like plan, BENCHMARKS.md: 23-28 s at 1 mm, 51-66 s at 0.5 mm).")
    dialect: Literal["auto", "iso", "linuxcnc"] = Field(
        "auto", description="Which posted dialect to run: 'auto' = linuxcnc when posted (explicit machine axes), "
                            "else iso.")
    riser_diameter_mm: float | None = Field(
        30.0, gt=0, le=10_000, description="A round riser under the centre of the stock's underside, from the table "
                                           "top up to it, that may never be cut, mm; null: none.")
    rapid_clearance_mm: float = Field(
        0.0, ge=0, le=100, description="A rapid closer than this to material counts as a rapid into material, mm.")
    mode: Literal["single_pass", "independent"] = Field(
        "single_pass", description="'single_pass': the programs proven to run exactly the moves the paths stage "
                                   "already ran on the carried stock (every position within the post's rounding, "
                                   "every tool and axis) are not run again: their figures and the stock are taken "
                                   "from that run (anything unproven falls back to 'independent', and the plan "
                                   "says why); 'independent': every program is run again on a fresh stock.")
    exact_finish: bool = Field(
        True, description="Also measure the finish exactly from the finishing moves (verification.finish): per scan "
                          "point the distance to the surface the ball swept, lines exactly (planning/simulate/"
                          "finish.py); false: only the stock model's deviation on its rays.")
    engagement: bool = Field(
        True, description="Measure the roughing end mill's engagement on every level move (verification: "
                          "engagement_max_deg, over_engagement_moves against paths.roughing.max_engagement_deg; "
                          "planning/simulate/engagement.py), on a height field of 0.25 mm columns along the set-up's "
                          "axis; false: not measured.")
    exact_finish_points: int = Field(
        50_000, ge=0, description="The exact finish is measured on at most this many scan points, drawn at random "
                                  "(fixed seed) from a larger scan: its figures are shares and percentiles, and "
                                  "50,000 points put a share within about 0.5 points (95 %); 0: every point. 10-40 "
                                  "microseconds a point on one core (the femur-like plan's 50,000: 0.6 s; a "
                                  "40,000-point range scan: 1.5 s).")


class FinishingParams(_Strict):
    """Ball-end finishing of each area by ball drop on the cloud (Sood 2015; Makki 2010 §4), with the
    ``tool`` above as the cutter."""

    enabled: bool = Field(True, description="Compute finishing paths for every area.")
    scallop_mm: float = Field(
        0.01, gt=0, le=5, description="Target scallop height between passes, mm, held on every curvature: each "
                                      "side step is the widest whose scallop, from the ball centres of the passes "
                                      "and the curvature across them, stays within it (on a plane "
                                      "2 sqrt(2 R h - h^2): 0.49 mm for R 3 mm, h 0.01 mm; narrower on concave, "
                                      "wider on convex sections; docs/design.md, 'the scallop on every curvature').")
    step_mm: float | None = Field(
        None, gt=0, le=50, description="Forward step between CL points along a pass, mm; null = R / 4. A move whose "
                                       "chord runs more than half tolerance_mm above the ball-drop height at its "
                                       "midpoint (concave along the pass) is bisected, at most six times.")
    margin_mm: float = Field(
        1.0, ge=0, le=100, description="How far the passes reach past the area into its neighbours (the overlap band), mm.")
    pattern: Literal["zigzag", "oneway"] = Field(
        "zigzag", description="'zigzag' alternates pass directions, linking neighbouring passes on the surface; "
                              "'oneway' cuts every pass the same way and retracts in between.")
    direction_deg: float | None = Field(
        None, ge=-180, le=180,
        description="Pass direction in the area frame, degrees from its X axis (the footprint's longer side); "
                    "null = along that side.")
    tolerance_mm: float = Field(
        0.01, gt=0, le=1, description="Gouge tolerance: no move comes closer than R - tolerance to a cloud point; "
                                      "also the chord / arc tolerance of CL reduction and arc fitting, mm.")
    reduce: bool = Field(True, description="Drop CL points a straight move replaces within the tolerance (Sood §4.4), gouge-checked.")
    arcs: bool = Field(True, description="Fit G2/G3 arcs in the pass planes within the tolerance, gouge-checked.")
    lead_mm: float = Field(
        1.0, ge=0, le=50, description="Length of the 45-degree lead-in and lead-out ramps, mm (vertical where a ramp "
                                      "would gouge; 0 = plunge straight down).")
    mode: Literal["3+2", "5axis"] = Field(
        "3+2", description="'3+2': every area at its set-up's fixed tool axis (Makki); '5axis': simultaneous 5-axis "
                           "finishing (Chui 2008): the passes are laid on the area as in 3+2 (the set-up axis is "
                           "the direction the ball drops along), and every position gets its own tool axis from its "
                           "contact normal with lead_deg and tilt_deg, kept in visibility.cone_deg, within "
                           "max_swing_deg of the set-up axis, under max_axis_rate_deg_per_mm, with the tool and "
                           "holder clear of the cloud and the rotary and linear travel (positions with no such axis "
                           "are cut out and reported). Roughing stays 3+2.")
    area_modes: dict[int, Literal["3+2", "5axis"]] = Field(
        default_factory=dict, description="Per set-up id (plan.json setups[].id): its finishing mode, overriding mode.")
    lead_deg: float = Field(
        0.0, ge=-45, le=45, description="5axis: lead angle, degrees: the axis leans along the feed direction (positive: "
                                        "the spindle ahead of the contact), after the tilt (Chui eq. 12 frame).")
    tilt_deg: float = Field(
        15.0, ge=-60, le=60, description="5axis: tilt angle from the reference normal about the feed direction, "
                                         "degrees (Chui 2008 eq. 12; about 15 keeps the tip, whose cutting speed is "
                                         "zero, off the surface); the cone then clamps it.")
    axis_frame: Literal["frenet", "surface"] = Field(
        "frenet", description="5axis: the reference normal of the tilt: 'frenet' the outward principal normal of the "
                              "ball-centre path (Chui eq. 9-12; the surface normal where the path is straight or curves "
                              "sideways), 'surface' the contact normal projected normal to the feed (Darboux frame).")
    max_axis_rate_deg_per_mm: float = Field(
        10.0, gt=0, le=180, description="5axis: the tool axis turns at most this much per mm of ball-centre path, degrees; "
                                        "where the surface turns faster than the cone allows to follow, the pass is "
                                        "broken (the tool leaves, turns in air and comes back).")
    pole_clearance_deg: float = Field(
        3.0, ge=0, le=45, description="5axis: no position's tool axis lies within this angle of the machine's rotary pole "
                                      "(the axis along the C axis at zero tilt), degrees: near it a small change of the "
                                      "tool axis needs a large turn of C, which the controls cannot follow on the "
                                      "surface (docs/programs.md, the pole).")
    max_swing_deg: float = Field(
        75.0, gt=0, lt=90, description="5axis: largest angle between a position's tool axis and its set-up's axis, "
                                       "degrees (retracts run along the set-up axis to the safe height, so the tool "
                                       "must lean less than 90 degrees from it).")


class RoughingParams(_Strict):
    """Z-level roughing of each set-up (Popescu 2014 binary map and graph linking; Tchanchane & Bey
    offset contours) with a flat or bull-nose end mill, from the stock box or, where the caller
    carries the stock through the set-ups, from the material left (rest roughing); entries into the
    material by helix or ramp."""

    enabled: bool = Field(True, description="Compute roughing paths for every area.")
    tool_type: Literal["flat", "bull"] = Field("flat", description="End mill: 'flat' or 'bull' (bull-nose).")
    diameter_mm: float = Field(10.0, gt=0, le=100, description="Roughing cutter diameter, mm.")
    corner_radius_mm: float = Field(
        0.0, ge=0, le=50, description="Corner radius of a bull-nose cutter, mm (0 for a flat end mill).")
    step_down_mm: float = Field(2.0, gt=0, le=50, description="Depth of cut between Z levels, mm.")
    stock_allowance_mm: float = Field(
        0.5, ge=0, le=20, description="Material left on the part for finishing, mm.")
    stock_margin_mm: float = Field(
        2.0, ge=0, le=200, description="Stock box: the part's box in the area frame grown by this on the sides and "
                                       "the top, mm.")
    stepover_mm: float | None = Field(
        None, gt=0, le=100, description="Distance between clearing lines, mm; null = 60 % of the diameter.")
    pattern: Literal["zigzag", "oneway"] = Field("zigzag", description="Clearing lines alternate or run one way.")
    window: bool = Field(
        True, description="Rough only over the set-up's own area (its footprint grown by the tools' reach); false: "
                          "all the stock the set-up can reach (with paths.carry_stock the later set-ups then have "
                          "less left).")
    entry: Literal["helix", "ramp", "plunge"] = Field(
        "helix", description="How a level is entered where material stands under the tool: 'helix' (falls back to "
                             "a ramp, then a plunge), 'ramp' (back and forth along the first line; falls back to a "
                             "helix, then a plunge) or 'plunge' (straight down everywhere). Either way the tool first "
                             "tries to come down in air beside the material and feed in; straight plunges into air or "
                             "holes already cut stay straight.")
    entry_angle_deg: float = Field(
        3.0, gt=0, le=45, description="Descent angle of helix and ramp entries from the horizontal, degrees.")
    entry_diameter_mm: float | None = Field(
        None, gt=0, le=200, description="Diameter of the circle the tool centre follows in a helix entry, mm (less "
                                        "than twice the cutter diameter); null = 70 % of the cutter diameter (no core "
                                        "is left under the cutter's centre).")
    ramp_length_mm: float | None = Field(
        None, gt=0, le=1000, description="Longest leg of a ramp entry, mm (at least the cutter radius); null = twice "
                                         "the cutter diameter.")
    max_engagement_deg: float = Field(
        90.0, gt=0, le=180, description="Bound on the roughing end mill's radial engagement, degrees: the angle of the "
                                        "cutter's circumference in the material (180 is a slot; acos(1 - ae / R) on a "
                                        "straight cut of radial depth ae: 60 degrees is a quarter of the diameter, 90 "
                                        "half). The verification measures every level move's engagement on the "
                                        "simulated stock and counts the moves over this bound (verification."
                                        "over_engagement_moves; simulate.engagement). Today's Z-level roughing steps "
                                        "over 60 % of the diameter (101.5 degrees) and slots where a pass enters fresh "
                                        "material, so it is over 90 by design; the bound is for judging a roughing "
                                        "at the full flute length, where shops keep 10-25 % of the diameter (37-60 "
                                        "degrees).")

    @model_validator(mode="after")
    def _corner(self) -> "RoughingParams":
        if self.corner_radius_mm > self.diameter_mm / 2.0:
            raise ValueError(f"corner_radius_mm {self.corner_radius_mm} exceeds the cutter radius {self.diameter_mm / 2.0}")
        if self.tool_type == "flat" and self.corner_radius_mm > 0:
            raise ValueError("a flat end mill has corner_radius_mm 0; use tool_type 'bull'")
        if self.entry_diameter_mm is not None and not self.entry_diameter_mm < 2.0 * self.diameter_mm:
            raise ValueError(f"entry_diameter_mm {self.entry_diameter_mm} must be less than twice the cutter diameter "
                             f"{2.0 * self.diameter_mm}")
        if self.ramp_length_mm is not None and self.ramp_length_mm < self.diameter_mm / 2.0:
            raise ValueError(f"ramp_length_mm {self.ramp_length_mm} must be at least the cutter radius "
                             f"{self.diameter_mm / 2.0}")
        return self


class SemiFinishingParams(_Strict):
    """Semi-finishing between the roughing and the finishing of each set-up (issue 31 item 3): a ball-end
    cutter of its own (held like ``tool``: the same stick-out, holder and gauge length) run over the area
    by ball drop like the finishing, its ball kept ``allowance_mm`` off the scan, so that the finishing
    meets a thin, even layer instead of the roughing's steps (docs/design.md, "Semi-finishing")."""

    enabled: bool = Field(False, description="Plan a semi-finishing pass for every area after its roughing.")
    diameter_mm: float = Field(8.0, gt=0, le=100, description="Ball-end semi-finishing cutter diameter, mm.")
    flute_length_mm: float | None = Field(
        None, gt=0, le=1000, description="Its cutting length from the tip, mm (at least its radius); null = "
                                         "tool.flute_length_mm, or the cutter radius when that is shorter.")
    allowance_mm: float = Field(
        0.2, ge=0, le=20, description="Material the pass leaves on the scan for the finishing, mm (less than "
                                      "paths.roughing.stock_allowance_mm): every move keeps the ball at least "
                                      "allowance_mm - tolerance_mm from every scan point.")
    scallop_mm: float = Field(
        0.05, gt=0, le=5, description="Target scallop height between passes over the allowance surface, mm (the side "
                                      "step as for the finishing: 2 sqrt(2 R' h - h^2) on a plane, R' the cutter "
                                      "radius plus allowance_mm).")
    step_mm: float | None = Field(
        None, gt=0, le=50, description="Forward step between CL points along a pass, mm; null = a quarter of the "
                                       "cutter radius plus allowance_mm.")
    tolerance_mm: float = Field(
        0.02, gt=0, le=1, description="How much closer than allowance_mm a move may come to a scan point, and the "
                                      "chord / arc tolerance of its CL reduction and arc fitting, mm.")
    margin_mm: float | None = Field(
        None, ge=0, le=100, description="How far the passes reach past the area, mm; null = paths.finishing.margin_mm.")
    pattern: Literal["zigzag", "oneway"] = Field("zigzag", description="As paths.finishing.pattern.")
    max_depth_mm: float | None = Field(
        None, gt=0, le=1000, description="Deepest cut: a position where the stock the roughing left stands more than "
                                         "this above the cutter's lower surface, within its radius (read along the "
                                         "tool axis), is cut out of the pass and left to the finishing, mm; null = "
                                         "paths.roughing.step_down_mm + stock_allowance_mm + simulate.resolution_mm "
                                         "(the roughing's stair and the stock model's reading error).")


class PathsParams(_Strict):
    """Per-area 3-axis tool paths in each set-up's frame (tool axis = +Z)."""

    finishing: FinishingParams = Field(default_factory=FinishingParams)
    roughing: RoughingParams = Field(default_factory=RoughingParams)
    semi_finishing: SemiFinishingParams = Field(default_factory=SemiFinishingParams)
    surface: Literal["auto", "points", "mesh"] = Field(
        "auto", description="What the finishing ball rests on and its gouge clearance is measured to. 'auto': the "
                            "points while their spacing is at most 20 % of the tool radius (Sood), else triangles: "
                            "the file's faces (mesh, scanner grid, relief image) or triangles through the points (the "
                            "Delaunay faces of circumradius <= 1.6 spacings; refused when that leaves points out); 'mesh': triangles always; 'points': the "
                            "points always (on a sparse cloud the ball can sink between them: a warning gives by "
                            "how much). plan.json paths_surface says which was used.")
    safe_clearance_mm: float = Field(
        5.0, gt=0, le=500, description="Retracts and rapids run this far above the highest point of the cloud, of "
                                       "the stock left by the set-ups before and of the fixtures under the area "
                                       "(tool tip), mm.")
    carry_stock: bool = Field(
        True, description="Carry one simulated stock (stock.*, at simulate.resolution_mm) through the set-ups in "
                          "their machining order: each set-up roughs only what the ones before left (rest "
                          "roughing), and every move is run on that stock, the fixtures and the machine's travel "
                          "before it is posted; what would collide or leave the travel is cut out (guard). "
                          "false: every set-up roughs from the full stock box and nothing is guarded.")
    guard_rapid_clearance_mm: float = Field(
        0.5, ge=0, le=50, description="The guard keeps every rapid this far from the stock it runs over, mm "
                                      "(a margin over simulate.rapid_clearance_mm for the programs' rounding).")

    @model_validator(mode="after")
    def _semi(self) -> "PathsParams":
        sf = self.semi_finishing
        if sf.enabled:
            if self.roughing.enabled and not sf.allowance_mm < self.roughing.stock_allowance_mm:
                raise ValueError(f"semi_finishing.allowance_mm {sf.allowance_mm} must be less than "
                                 f"roughing.stock_allowance_mm {self.roughing.stock_allowance_mm}: the pass removes "
                                 "what the roughing leaves above it")
            if not self.finishing.enabled:
                raise ValueError("semi_finishing needs finishing.enabled: the pass leaves its allowance for the "
                                 "finishing")
        return self


class PostParams(_Strict):
    """NC programs: one file per area per dialect, and the neutral JSON moves."""

    dialects: list[Literal["iso", "linuxcnc"]] = Field(
        default_factory=lambda: ["iso", "linuxcnc"],
        description="'iso': ISO/Fanuc-style with a G68.2 tilted work plane; 'linuxcnc': explicit rotary positioning "
                    "then 3-axis XYZ in the machine frame.")
    program_number: int = Field(1000, ge=1, le=9999, description="O-number of the first area's program (areas count up).")
    finishing_tool_number: int = Field(1, ge=1, le=999, description="T number of the ball-end cutter.")
    roughing_tool_number: int = Field(2, ge=1, le=999, description="T number of the roughing end mill.")
    spindle_rpm: float = Field(12_000, gt=0, le=100_000, description="Finishing spindle speed, rev/min.")
    feed_mm_min: float = Field(1_500, gt=0, le=100_000, description="Finishing cutting feed, mm/min.")
    roughing_spindle_rpm: float = Field(8_000, gt=0, le=100_000, description="Roughing spindle speed, rev/min.")
    roughing_feed_mm_min: float = Field(2_000, gt=0, le=100_000, description="Roughing cutting feed, mm/min.")
    semi_finishing_tool_number: int = Field(3, ge=1, le=999, description="T number of the semi-finishing ball-end "
                                                                         "cutter (paths.semi_finishing).")
    semi_finishing_spindle_rpm: float = Field(10_000, gt=0, le=100_000, description="Semi-finishing spindle speed, rev/min.")
    semi_finishing_feed_mm_min: float = Field(2_000, gt=0, le=100_000, description="Semi-finishing cutting feed, mm/min.")
    plunge_mm_min: float = Field(500, gt=0, le=100_000, description="Plunge, ramp and lead feed, mm/min.")
    rapid_mm_min: float = Field(
        15_000, gt=0, le=200_000, description="Rapid rate used only to estimate the machining time, mm/min.")
    coolant: bool = Field(True, description="Flood coolant on (M8) while cutting.")
    decimals: int = Field(4, ge=2, le=6, description="Decimal places of coordinates in the programs.")
    rotary_sign: tuple[Literal[1, -1], Literal[1, -1]] = Field(
        (1, 1), description="Multiply the (tilt, rotary) angles by these signs in the LinuxCNC post, for a control "
                            "that counts an axis the other way than the planner (planning/orientations/kinematics.py).")
    max_arc_radius_mm: float = Field(
        500.0, gt=0, le=100_000,
        description="Largest radius of a G2/G3 arc, mm: the posts write any arc of a larger radius as G1 chords "
                    "within 0.002 mm of it (a single G1 where it is straighter than that), since a near-straight "
                    "arc of metres' radius has its centre and circle far off the part.")


class PlanConfig(_Strict):
    """One plan configuration document, grouped by pipeline stage (docs/design.md parameter names)."""

    input: InputParams = Field(default_factory=InputParams)
    normals: NormalsParams = Field(default_factory=NormalsParams)
    orientations: OrientationsParams = Field(default_factory=OrientationsParams)
    machine: MachineParams = Field(default_factory=MachineParams)
    tool: ToolParams = Field(default_factory=ToolParams)
    fixtures: FixturesParams = Field(default_factory=FixturesParams)
    visibility: VisibilityParams = Field(default_factory=VisibilityParams)
    setups: SetupsParams = Field(default_factory=SetupsParams)
    areas: AreasParams = Field(default_factory=AreasParams)
    paths: PathsParams = Field(default_factory=PathsParams)
    post: PostParams = Field(default_factory=PostParams)
    stock: StockParams = Field(default_factory=StockParams)
    simulate: SimulateParams = Field(default_factory=SimulateParams)

    @model_validator(mode="after")
    def _tool_numbers(self) -> "PlanConfig":
        if self.paths.semi_finishing.enabled:
            p = self.post
            if p.semi_finishing_tool_number in (p.finishing_tool_number, p.roughing_tool_number):
                raise ValueError(f"post.semi_finishing_tool_number {p.semi_finishing_tool_number} is also the "
                                 "finishing or the roughing tool's T number: each tool needs its own")
            sf = self.paths.semi_finishing
            if sf.diameter_mm / 2.0 > self.tool.stickout_mm:
                raise ValueError(f"paths.semi_finishing.diameter_mm {sf.diameter_mm}: its radius exceeds "
                                 f"tool.stickout_mm {self.tool.stickout_mm}")
        return self

    def to_json_dict(self) -> dict[str, Any]:
        """The configuration as JSON-ready data, with the public names (``visibility.global``)."""
        return self.model_dump(mode="json", by_alias=True)


def _model_in(annotation) -> type[BaseModel] | None:
    """The parameter group (a pydantic model) an annotation holds, directly or in Optional/Annotated."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _names(model: type[BaseModel]) -> list[str]:
    """The public names of a group's parameters (the alias where there is one)."""
    return [f.alias or name for name, f in model.model_fields.items()]


def _did_you_mean(loc: tuple) -> str:
    """For an unknown parameter at ``loc`` (the path of keys): the nearest known name in its group
    (``difflib``, as the path would be written), or '' when none is near."""
    model: type[BaseModel] | None = PlanConfig
    for key in loc[:-1]:
        field = next((f for name, f in model.model_fields.items() if key in (name, f.alias)), None)
        model = None if field is None else _model_in(field.annotation)
        if model is None:
            return ""
    near = difflib.get_close_matches(str(loc[-1]), _names(model), n=1, cutoff=0.6)
    return ".".join([*map(str, loc[:-1]), near[0]]) if near else ""


def _describe(err: dict[str, Any]) -> str:
    loc = tuple(err.get("loc", ()))
    path = ".".join(str(p) for p in loc) or "(document)"
    msg = err.get("msg", "invalid")
    if err.get("type") == "extra_forbidden":
        near = _did_you_mean(loc) if loc else ""
        return f"{path}: unknown parameter" + (f" (did you mean {near}?)" if near else "")
    if "input" in err and err.get("type") != "missing":
        shown = json.dumps(err["input"], default=str)
        if len(shown) > 80:
            shown = shown[:77] + "..."
        hint = ""
        limit = (err.get("ctx") or {}).get("le")
        value = err["input"]
        if err.get("type") == "less_than_equal" and limit == 1 and isinstance(value, (int, float)) \
                and not isinstance(value, bool) and 1 < value <= 100:
            hint = f" (a fraction: {value:g} % is {value / 100:g})"
        return f"{path} = {shown}: {msg}{hint}"
    return f"{path}: {msg}"


def parse_config(data: dict[str, Any] | None) -> PlanConfig:
    """Validate a configuration document; raise :class:`ParameterError` naming every bad parameter."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ParameterError("the configuration must be a JSON object grouped by stage, e.g. "
                             '{"setups": {"coverage": 0.95}}')
    try:
        return PlanConfig.model_validate(data)
    except ValidationError as exc:
        problems = [_describe(e) for e in exc.errors()]
        raise ParameterError("invalid parameters: " + "; ".join(problems), problems=problems) from None


def _parse_value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def apply_overrides(data: dict[str, Any], assignments: list[str]) -> dict[str, Any]:
    """Apply ``path=value`` assignments (``setups.coverage=0.9``; value parsed as JSON, else a string)."""
    out = json.loads(json.dumps(data))
    for item in assignments:
        if "=" not in item:
            raise ParameterError(f"--set expects path=value, got {item!r}")
        path, value = item.split("=", 1)
        keys = [k for k in path.strip().split(".") if k]
        if not keys:
            raise ParameterError(f"--set has an empty parameter path in {item!r}")
        node = out
        for k in keys[:-1]:
            nxt = node.setdefault(k, {})
            if not isinstance(nxt, dict):
                raise ParameterError(f"--set {path}: {k} is not a group of parameters")
            node = nxt
        node[keys[-1]] = _parse_value(value)
    return out
