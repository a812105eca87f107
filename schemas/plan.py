"""The plan result (``plan.json``): the contract clients read. Its JSON Schema is exported from here.

Large arrays never travel inside this document: they are in ``plan.npz`` (see docs/design.md,
"Plan output contract") and the other artifacts named in ``artifacts``.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas.params import PlanConfig

SCHEMA_VERSION = "1.0"


class _Out(BaseModel):
    model_config = ConfigDict(extra="forbid")


class InputSummary(_Out):
    name: str | None = Field(None, description="File name of the submitted cloud, if any.")
    format: str = Field(..., description="Detected file format.")
    n_points: int = Field(..., ge=1, description="Points read, after unit conversion.")
    units: str = Field(..., description="Unit declared for the file (everything below is in mm).")
    bbox_min_mm: tuple[float, float, float]
    bbox_max_mm: tuple[float, float, float]
    has_normals: bool = Field(..., description="Whether the file carried normals.")
    n_faces: int = Field(0, ge=0, description="Triangles the file carried (meshes, scanner grids, reliefs); 0 for a "
                                              "plain cloud.")
    n_points_planned: int | None = Field(
        None, description="Points the plan ran on: for a mesh its vertices plus the points laid on its edges and "
                          "facets (input.mesh_sample_mm); null when the file's points themselves.")
    facet_spacing_mm: float | None = Field(None, description="Spacing of the points laid on a mesh's facets, mm.")


class NormalsSummary(_Out):
    method: Literal["sphere_throwing", "input", "facets"]
    n_sampled: int = Field(..., ge=0, description="Points with a normal (the sampled points all later stages use).")
    sampled_fraction: float = Field(..., ge=0, le=1)
    sphere_diameter_mm: float | None = None
    grid_spacing_mm: float | None = Field(None, description="Grid spacing actually used, mm.")


class OrientationsSummary(_Out):
    sampling: str
    n_candidates: int = Field(..., description="Axes on the Gaussian sphere before machine visibility.")
    n_machine_feasible: int = Field(..., description="Axes within the machine's rotary travel.")
    n_kept: int = Field(..., description="Axes left after the setups.min_points filter.")
    machine_profile: str
    kinematics: str
    rotary_axes: tuple[str, str] = Field(..., description="Names of the (tilt, rotary) machine axes, e.g. ('B', 'C').")


class AxisFilters(_Out):
    """How many sampled points each visibility filter removed for one candidate axis (filters run in
    this order; each sees only what the previous ones kept)."""

    candidate: int = Field(..., ge=0, description="Index into the candidate axes before machine visibility.")
    phi_deg: float
    theta_deg: float
    machine: int = Field(..., ge=0, description="Removed by rotary travel (all points, or none).")
    cone: int = Field(..., ge=0, description="Removed by the tool cone [v1, v2] about the normal.")
    travel: int = Field(..., ge=0, description="Removed by X/Y/Z travel.")
    fixture_collision: int = Field(..., ge=0, description="Removed by tool/holder collisions with fixtures or the table.")
    cloud_collision: int = Field(..., ge=0, description="Removed by tool/holder collisions with the cloud.")
    visible: int = Field(..., ge=0, description="Left visible.")


class VisibilitySummary(_Out):
    """Visibility filters (Makki §2.2.2-2.2.4): which ran, where the part was placed, and per axis the
    points each filter removed."""

    global_checked: bool = Field(..., description="Tool, holder and fixture collisions were checked.")
    travel_checked: bool = Field(..., description="X/Y/Z travel was checked.")
    obstacles: str = Field(..., description="'sampled' or 'all': which cloud points the collision test used.")
    n_obstacle_points: int = Field(..., ge=0, description="Points the collision test checked (cloud and forbidden points).")
    placement_mm: tuple[float, float, float] = Field(..., description="Part-frame origin in the table frame, mm.")
    table_z_mm: float | None = Field(None, description="Table top in the part frame (z), mm; null = table not checked.")
    pairs_cone: int = Field(..., ge=0, description="(point, axis) pairs inside the tool cone on feasible axes.")
    pairs_visible: int = Field(..., ge=0, description="Pairs left after every filter.")
    removed_total: dict[str, int] = Field(..., description="Pairs removed per filter, all axes together.")
    per_axis: list[AxisFilters]


class FrameSummary(_Out):
    """An area's machining frame: tool axis = +Z (planning/toolpath/frames.py)."""

    origin_mm: tuple[float, float, float] = Field(..., description="Frame origin in the part frame, mm.")
    x_axis: tuple[float, float, float] = Field(..., description="Frame X (pass direction) in the part frame.")
    y_axis: tuple[float, float, float]
    z_axis: tuple[float, float, float] = Field(..., description="Frame Z = the tool axis.")


class GuardSummary(_Out):
    """What the guard (issue 16; planning/toolpath/guard.py) found and changed in one operation, run on
    the carried stock, the fixtures and the machine's travel before posting."""

    found: dict[str, int] = Field(
        default_factory=dict, description="Moves that offended on the first run, per class: 'rapid' (a rapid into "
                                          "material), 'holder' (shank or holder in material), 'fixture' (the tool "
                                          "in a fixture, the riser or the table), 'travel' (beyond the travel).")
    rapids_to_feed: int = Field(0, description="Rapids into material replaced by a way over the stock: up along the tool axis to the safe height, across, and down as a plunge feed.")
    dropped: int = Field(0, description="Path points cut out (the path retracts before and comes down after).")
    truncated: int = Field(0, description="Moves cut off at the end because they still offended after the last "
                                          "round (0 when the guard repaired everything).")
    rounds: int = Field(0, description="Runs on the stock.")
    removed_mm3: float = Field(0.0, description="Material the operation removes from the carried stock, mm^3.")


class FiveAxisLinksSummary(_Out):
    """The links between the passes of a 5-axis finishing path planned on the stock (issue 33 item 1):
    up each cutting position's own tool axis to a clearance over the stock, across, down; checked
    on the stock, the fixtures, the travel and the rotary pole when planned."""

    n_links: int = Field(..., description="Links between two cutting positions with a rapid in them.")
    n_planned: int = Field(..., description="Links replaced by a link over the stock.")
    n_kept: int = Field(..., description="Links kept as the finishing made them (through the safe height): no "
                                         "lift cleared every check.")
    n_round_pole: int = Field(0, description="Planned links whose tool axis turns round the machine's rotary pole "
                                             "(tilt held, rotary axis turning) instead of through it.")
    n_holder: int = Field(0, description="Planned links whose feed off or onto the surface meets the stock with the "
                                         "shank or holder (the guard cuts the cutting position beside it out).")
    by_lift: dict[str, int] = Field(default_factory=dict, description="Planned links per lift over the higher of "
                                                                       "their two clear heights, mm; 'safe': both "
                                                                       "ends up their own axes to the safe height.")
    kept_by: dict[str, int] = Field(default_factory=dict, description="Kept links per first failing check at the "
                                                                       "highest lift: column, stock, obstacles, "
                                                                       "travel, pole.")
    length_before_mm: float = Field(..., description="Reference-point length of the replaced links before, mm.")
    length_after_mm: float = Field(..., description="The same after, mm.")


class FiveAxisSummary(_Out):
    """Simultaneous 5-axis finishing of one area (issue 19; paths.finishing.mode '5axis'): the axes given
    to the ball-drop positions and the 3D biarcs of the ball-centre path (Chui 2008)."""

    n_positions: int = Field(..., description="Positions on the part (dense CL points) given a tool axis.")
    n_alternatives: int = Field(..., description="Positions whose lead/tilt axis was not admissible and that took "
                                                 "the nearest admissible axis on rings inside the cone.")
    blocked: dict[str, int] = Field(
        default_factory=dict, description="Positions cut out, per reason: 'no_axis' (no admissible axis: cloud, "
                                          "stock, swing or travel), 'between' (the move into it not admissible "
                                          "halfway), 'rate' (the axis would turn faster than "
                                          "max_axis_rate_deg_per_mm), 'floor' (the ball below the part's underside), "
                                          "'flip' (the machine would change rotary solution there, swinging "
                                          "through the pole on the surface).")
    cone_deg: tuple[float, float] = Field(..., description="Smallest and largest angle between a kept axis and its "
                                                           "contact normal, degrees.")
    swing_deg: float = Field(..., description="Largest angle between a kept axis and the set-up axis, degrees.")
    max_rate_deg_per_mm: float = Field(..., description="Fastest axis turn between neighbouring positions kept, "
                                                        "degrees per mm of ball-centre path.")
    n_moves_before_biarcs: int = Field(..., description="Cutting moves of the ball-centre path the biarcs fit.")
    n_biarcs: int = Field(..., description="3D biarcs fitted to the ball-centre path within tolerance_mm (Chui App. A).")
    n_arcs: int = Field(..., description="Arcs (and straight pieces) of those biarcs: the moves after fitting.")
    biarc_max_error_mm: float = Field(..., description="Largest distance of a ball-centre position from its biarc, mm.")
    n_unwinding_links: int = Field(
        0, description="Short links routed through the safe height so that the post turns a continuous C back "
                       "there (the C register: machine profile rotary_register_deg).")
    links: FiveAxisLinksSummary | None = Field(
        None, description="The links planned on the stock (None: planned without a carried stock).")
    biarc_min_clearance_mm: float = Field(
        ..., description="Smallest distance between the biarc curve (as chords within 0.002 mm) and any cloud point, "
                         "mm; the programs are G1 through the positions, the biarcs are the fitted curve reported "
                         "(gouge free when >= R - tolerance_mm).")


class FinishingSummary(_Out):
    """Ball-end finishing of one area (frame units: mm)."""

    n_passes: int = Field(..., description="Passes, summed over the area's regions (a line across two regions counts twice).")
    n_regions: int = Field(1, description="Connected regions of the area finished one after the other.")
    step_over_mm: float
    n_cl: int = Field(..., description="CL points (ball centres) of the final path, all moves; plan.npz cl_i.")
    n_cl_before_reduction: int = Field(..., description="CL points before CL reduction and arc fitting.")
    n_arcs: int = Field(..., description="G2/G3 moves.")
    n_retracts: int = Field(..., description="Retracts to the safe height between stretches.")
    length_mm: float = Field(..., description="Cutting length (feed and arc moves), mm.")
    tolerance_mm: float
    min_clearance_mm: float = Field(
        ..., description="Smallest distance between the ball-centre path (every feed and arc move) and any cloud "
                         "point, measured on the final path; gouge free when >= R - tolerance_mm (capped at R).")
    gouge_free: bool = Field(..., description="min_clearance_mm >= R - tolerance_mm.")
    holder_collisions: int = Field(
        ..., description="CL points where the cutter above the ball, the shank or the holder meets a cloud point.")
    fixture_collisions: int = Field(
        ..., description="CL points where the tool assembly meets a fixture or the table.")
    machining_time_s: float = Field(..., description="ESTIMATE from the tool path before posting: at the post's "
                                                    "feeds and rapid rate, no acceleration, s (the time to plan "
                                                    "on is figures.machining_time_s).")
    blocked_cl: dict[str, int] = Field(
        default_factory=dict, description="CL points cut out of the passes before reduction, per reason: 'cloud' "
                                          "(cutter above the ball, shank or holder meets the scan), 'stock' (shank or "
                                          "holder in the carried stock), 'fixture', 'travel', 'underside' (ball below "
                                          "the part's underside); a point may count under several.")
    unmachined_points: int = Field(0, description="Scan points of the area that no kept finishing move of any set-up "
                                                  "reaches.")
    handed_in_points: int = Field(0, description="Scan points of other areas, left unmachined by the set-ups before, "
                                                 "that this set-up sees and finished.")
    guard: GuardSummary | None = None
    mode: Literal["3+2", "5axis"] = Field("3+2", description="Fixed axis (3+2) or an axis per position (5axis).")
    five_axis: FiveAxisSummary | None = None


class RoughingSummary(_Out):
    """Z-level roughing of one area: from a stock box, or (paths.carry_stock) from the stock the set-ups
    before left."""

    n_levels: int
    length_mm: float = Field(..., description="Cutting length, mm.")
    air_mm: float = Field(..., description="Rapid length, mm.")
    n_retracts: int
    min_clearance_mm: float | None = Field(
        ..., description="Smallest distance between the cutter and any cloud point along the path, mm (>= the "
                         "stock allowance); null when no cloud point comes within a tool radius of the path.")
    stock_box_mm: tuple[tuple[float, float, float], tuple[float, float, float]] = Field(
        ..., description="Stock box (min corner, max corner) in the area frame, mm.")
    machining_time_s: float = Field(..., description="ESTIMATE from the tool path before posting, s (the time to "
                                                     "plan on is figures.machining_time_s).")
    rest: bool = Field(False, description="Rest roughing: only the material the set-ups before left was cut.")
    allowance_left_mm: dict[str, float] | None = Field(
        None, description="The stock over the area's scan points when its finishing starts (after this roughing "
                          "and every earlier set-up), read along their normals on the carried stock, mm: p05, p50, "
                          "p95, max, and n points read. Uniform at stock_allowance_mm where the roughing reached; "
                          "more in corners the end mill cannot enter and where its holder could not go.")
    n_helix: int = Field(0, description="Entries into material by a helix.")
    n_ramps: int = Field(0, description="Entries into material by a ramp.")
    n_plunges_into_material: int = Field(0, description="Straight plunges into material (no helix or ramp fitted).")
    n_pieces_left: int = Field(0, description="Pieces of a level left uncut because no side entry, helix or ramp "
                                              "fits and a straight plunge into material is not made (roughing on "
                                              "the carried stock); their material is left for the next levels' "
                                              "flutes or for finishing.")
    left_length_mm: float = Field(0.0, description="Length of those pieces, mm.")
    guard: GuardSummary | None = None


class SemiFinishingSummary(_Out):
    """The semi-finishing pass of one area (paths.semi_finishing; planning/toolpath/semi_finishing.py)."""

    diameter_mm: float = Field(..., description="The ball-end cutter's diameter, mm.")
    allowance_mm: float = Field(..., description="Material it leaves on the scan for the finishing, mm.")
    n_passes: int = Field(..., description="Passes planned over the area (before the cut-out).")
    step_over_mm: float = Field(..., description="Side step of the passes on a plane, mm.")
    n_cl: int = Field(..., description="Moves of the final path.")
    n_arcs: int = Field(0, description="Arcs (G2/G3) among them.")
    length_mm: float = Field(..., description="Feed and arc length, mm.")
    min_clearance_mm: float = Field(
        ..., description="Smallest distance from a scan point to the cutter's ball along the final path, mm (at "
                         "least allowance_mm - tolerance_mm).")
    blocked_cl: dict[str, int] = Field(
        default_factory=dict, description="Positions cut out, by reason (cloud, fixture, stock: the shank or holder "
                                          "on the roughing's stock, travel, underside).")
    allowance_before_mm: dict[str, float] | None = Field(
        None, description="The stock over the area's scan points along their normals before the pass (after the "
                          "roughing), mm: p05, p50, p95, max, n (as roughing.allowance_left_mm).")
    allowance_after_mm: dict[str, float] | None = Field(
        None, description="The same after the pass: what the finishing meets, mm.")
    allowance_reached_mm: dict[str, float] | None = Field(
        None, description="The same after the pass over the points it reaches (its kept moves' ball of radius "
                          "diameter/2 + allowance within the scallop, the tolerance and the sampling's slack): "
                          "the uniform layer it leaves, where it could go, mm.")
    reached_share: float = Field(0.0, description="Share of the area's points the pass reaches.")
    machining_time_s: float = Field(..., description="ESTIMATE from the tool path before posting, s.")
    guard: GuardSummary | None = None


class AreaPathSummary(_Out):
    """What the tool paths of one area amount to."""

    frame: FrameSummary
    safe_z_mm: float = Field(..., description="Ball-centre height of retracts and rapids in the area frame, mm.")
    finishing: FinishingSummary | None = None
    roughing: RoughingSummary | None = None
    semi_finishing: SemiFinishingSummary | None = None
    programs: dict[str, str] = Field(default_factory=dict, description="NC program artifact per post dialect.")
    moves: str | None = Field(None, description="Neutral moves artifact: the JSON (format scanmill-neutral-moves), gzip "
                                                "compressed, area_<i>.moves.json.gz.")
    moves_npz: str | None = Field(None, description="The same moves as arrays, area_<i>.moves.npz (format "
                                                    "scanmill-neutral-moves-npz; planning/report/moves_files.py).")
    seconds: dict[str, float] = Field(default_factory=dict, description="Time per path step, s.")


class AreaRegions(_Out):
    """The shape of one area on the points' neighbourhood graph (planning/areas/regions.py)."""

    n_regions: int = Field(..., description="Connected regions of the area (each is machined on its own).")
    largest_region_share: float = Field(..., description="Share of the area's sampled points in its largest region.")
    n_small_regions: int = Field(
        ..., description="Regions under areas.min_region_mm2 that stay: each holds a point only this set-up sees.")
    min_regions: int = Field(
        ..., description="Lower bound on n_regions from the visibility alone: connected pieces of the visible set "
                         "holding a point no other chosen set-up sees.")
    n_visible_regions: int = Field(
        ..., description="Connected pieces (of at least areas.min_region_mm2) of the set of points this set-up sees.")
    area_mm2: float = Field(..., description="Surface of the area, mm^2 (sum of the points' areas).")
    seam_mm: float = Field(..., description="Length of the area's border with other areas, mm (Crofton estimate "
                                            "over the cut graph edges, docs/design.md stage 6).")


class AreasSummary(_Out):
    """How the points were split into areas (stage 6)."""

    method: Literal["graphcut", "per_point"]
    n_regions: int = Field(..., description="Connected regions of all areas together.")
    seam_mm: float = Field(..., description="Total seam length between areas, mm (each seam counted once).")
    label_change_share: float = Field(
        ..., description="Share of neighbour pairs of the sampled points (the kNN graph) carrying different areas.")


class Setup(_Out):
    id: int = Field(..., ge=0, description="Area / set-up number, also the label in plan.npz.")
    candidate_index: int = Field(..., ge=0, description="Index into plan.npz candidate_axes.")
    tool_axis: tuple[float, float, float] = Field(..., description="Unit tool axis in the part frame (part -> spindle).")
    phi_deg: float = Field(..., description="Polar angle of the tool axis from +Z, degrees.")
    theta_deg: float = Field(..., description="Azimuth of the tool axis from +X towards +Y, degrees.")
    rotary_deg: dict[str, float] = Field(..., description="Machine rotary positions, degrees, by axis name.")
    n_visible: int = Field(..., description="Sampled points this axis may machine.")
    n_points: int = Field(..., description="Sampled points labelled with this set-up (integrated ones included).")
    n_integrated: int = Field(..., description="Of those, leftovers attached by distance (accessibility not guaranteed).")
    n_input_points: int = Field(..., description="Points of the whole submitted cloud labelled with this set-up.")
    regions: AreaRegions | None = Field(None, description="Connected regions and seam of the area.")
    path: AreaPathSummary | None = Field(
        None, description="Tool path summary (length, passes, CL count, clearance, programs); null when no path "
                          "was computed (paths disabled, or an area without points).")


class Selection(_Out):
    status: Literal["optimal", "feasible", "infeasible", "unknown"] = Field(
        ..., description="'optimal': proven minimum overlap for the fewest set-ups; 'feasible': the time limit "
                         "stopped the proof (see gap); 'infeasible': no max_setups orientations reach the coverage; "
                         "'unknown': the time limit hit before any set of orientations reaching the coverage was "
                         "found or ruled out (the best coverage found is reported).")
    solver: str
    k: int
    covered: int
    required_covered: int
    coverage: float
    overlap: int = Field(..., description="Sampled points seen by two or more chosen orientations.")
    lower_bound: int | None = None
    gap: float | None = None
    best_coverage_at_max: float | None = None
    n_classes: int
    seconds: float
    message: str


class Timing(_Out):
    stage: str
    seconds: float


class Artifacts(_Out):
    plan_npz: str = "plan.npz"
    segmentation_ply: str = "segmentation.ply"
    preview_png: str = "preview.png"
    deviation_ply: str | None = Field(None, description="Every scan point coloured by its deviation from the "
                                                        "simulated result, with a deviation_mm property.")
    deviation_png: str | None = Field(None, description="Views of the deviation with a colour bar in mm.")
    stock_ply: str | None = Field(None, description="The simulated final stock as a triangle mesh.")
    unmachined_png: str | None = Field(None, description="Views of the scan with the points no kept finishing move "
                                                         "reaches in red (plan.json unmachined).")
    placed_ply: str | None = Field(None, description="fixtures.placement 'auto': every scan point as placed on the table "
                                                     "(the plan's frame: rotation and translation in plan.json placement).")
    viewer_json: str | None = Field(
        "viewer.json", description="Index of the browser viewer's data (format scanmill-viewer): the set-ups, the "
                                   "verdict and the table of the little-endian arrays in viewer.points.bin (the scan: "
                                   "quantised positions, area, flags, deviation) and viewer.paths.bin (tool-tip paths "
                                   "per area and operation); docs/viewer.md.")


class VerificationOffence(_Out):
    """One move of one program that would harm the machine, the tool or the part."""

    kind: Literal["travel", "rapid_into_material", "holder_collision", "fixture_collision", "rotary_speed"] = Field(
        ..., description="'travel': an axis beyond its limit (a continuous C beyond its register); 'rotary_speed': a "
                         "feed move that turns a rotary axis faster than the profile's *_feed_max_deg_min; 'rapid_into_material': a G0 whose tool meets stock; "
                         "'holder_collision': the shank or holder meets stock or part; 'fixture_collision': any part "
                         "of the tool meets a fixture, the riser or the table.")
    program: str = Field(..., description="Program artifact.")
    line: int = Field(..., ge=1, description="1-based line of the program text.")
    position_mm: tuple[float, float, float] = Field(..., description="Tool tip at the end of the move, part frame, mm.")
    amount: float = Field(..., description="Depth of the contact (mm), excess beyond the limit (mm or deg), or "
                                           "for 'rotary_speed' the rate over the limit (ratio - 1).")
    detail: str = Field("", description="Which axis or solid.")


class DeviationFigures(_Out):
    """Signed distance from the simulated final surface to the scan points (positive: material left)."""

    n_points: int
    finished_share: float = Field(
        ..., description="Share of the points within paths.finishing.tolerance_mm + scallop_mm (+ the measuring "
                         "bound) of the final surface on both sides.")
    left_p50_mm: float
    left_p95_mm: float
    left_max_mm: float
    gouge_max_mm: float = Field(..., description="Deepest cut below a scan point, mm (0: none): read as the highest of "
                                                "the four rays around it (a cut must show on all four), and for the "
                                                "points read as gouged, measured exactly against the tools of the "
                                                "moves that ran (planning/simulate/gouge.py).")
    n_gouged: int = Field(..., description="Points cut below the scan by more than the tolerance: read so on the stock "
                                           "model (beyond the tolerance and the measuring bound) and confirmed by the "
                                           "exact depth inside a tool of a move that ran.")
    n_suspected: int = Field(0, description="Points the stock model read as gouged; those the exact measure did not "
                                            "confirm are resolution artefacts (cusps and seams finer than the rays).")


class FinishFigures(_Out):
    """The finish measured exactly from the finishing moves (planning/simulate/finish.py): per scan point,
    the distance from the point to the surface the finishing ball swept on the programs' feed moves
    (positive: material left over it; negative: the ball went below it), lines exactly, arcs as the
    reader's chords. Not on the stock model's rays: a scallop between passes is seen."""

    n_points: int = Field(..., description="Scan points measured: all of them, or simulate.exact_finish_points drawn "
                                           "at random from a larger scan.")
    limit_mm: float = Field(..., description="paths.finishing.scallop_mm + tolerance_mm: at most this much material "
                                             "left counts as finished, mm.")
    finished_share: float = Field(
        ..., description="Share of the points the ball came within limit_mm above and no deeper than tolerance_mm "
                         "(plus the reader's 0.005 mm chords and the programs' last decimal) below.")
    reached_share: float = Field(..., description="Share of the points some finishing move came near (a 4 mm piece "
                                                  "of it centred within 2 R + 3 mm); the others are not finished.")
    left_p50_mm: float = Field(..., description="Median material left over the reached points (0 where cut below), mm.")
    left_p95_mm: float = Field(..., description="95th percentile of the material left over the reached points, mm.")
    left_max_mm: float = Field(..., description="Most material left over a reached point, mm.")
    scallop_p95_mm: float = Field(..., description="95th percentile of the material left over the finished points: "
                                                   "the scallop the passes leave where they finish, mm.")
    below_max_mm: float = Field(..., description="Deepest the finishing ball went below a scan point, mm (0: nowhere).")
    n_below_tolerance: int = Field(..., description="Points the finishing ball went below by more than tolerance_mm "
                                                    "(plus the reader's chords and the programs' last decimal).")


class OperationFigures(_Out):
    """What one tool's moves in an area's program do on the simulated stock: how far they feed, how much of
    that cuts nothing (air), what they remove and how long they take. Air is measured on the stock model at
    ``simulate.resolution_mm``: a feed move whose swept tool removes less than 1e-6 mm^3 there counts as air
    (a finishing pass that takes off less than a ray's reach may read as air; the roughing figures are the
    ones to judge air cutting by)."""

    tool: int = Field(..., description="The tool's T number.")
    operation: Literal["roughing", "semi_finishing", "finishing"] = Field(
        ..., description="'roughing' for post.roughing_tool_number, 'semi_finishing' for "
                         "post.semi_finishing_tool_number (when paths.semi_finishing is enabled), else 'finishing'.")
    feed_mm: float = Field(..., description="Length of the feed moves (G1, G2, G3), mm.")
    air_feed_mm: float = Field(..., description="Length of the feed moves that removed no material, mm.")
    air_share: float = Field(..., description="air_feed_mm / feed_mm (0 without feed moves).")
    rapid_mm: float = Field(..., description="Length of the rapids (G0), mm.")
    removed_mm3: float = Field(..., description="Material these moves removed from the carried stock, mm^3.")
    machining_time_s: float = Field(..., description="Feed moves at their program lines' F words, rapids at "
                                                     "post.rapid_mm_min, s.")
    plunges_into_material: int = Field(0, description="Feed moves within 10 degrees of straight down the tool "
                                                      "axis that removed material (roughing end mill only).")
    engagement_max_deg: float | None = Field(
        None, description="Roughing end mill only: the largest equivalent engagement angle of its level moves, degrees "
                          "(the angle of a straight cut that removes the same area per length advanced, at the worst "
                          "height of the flutes: 180 is a slot; planning/simulate/engagement.py); null: not measured "
                          "(simulate.engagement false, another tool, or a tool that changes axis while it feeds).")
    engagement_p95_deg: float | None = Field(
        None, description="The 95th percentile of the level moves' engagement, weighted by their length, degrees.")
    over_engagement_moves: int = Field(
        0, description="Level feed moves of the roughing end mill whose engagement exceeds "
                       "paths.roughing.max_engagement_deg (reported; not part of the verdict).")
    over_engagement_mm: float = Field(0.0, description="Their feed length, mm.")


class AreaVerification(_Out):
    """What the simulation found for one area's program."""

    area: int
    program: str
    n_moves: int
    removed_mm3: float
    machining_time_s: float = Field(..., description="The program as the control runs it: feed moves at their "
                                                    "lines' F words (G93 inverse time included), rapids at "
                                                    "post.rapid_mm_min, no acceleration, s.")
    rapids_into_material: int
    holder_collisions: int
    fixture_collisions: int
    travel_excursions: int
    rotary_feed_excesses: int = Field(
        0, description="Feed moves (program lines) whose tilt or rotary axis turns faster than the machine "
                       "profile's tilt_feed_max_deg_min / rotary_feed_max_deg_min at the line's F word (part of the "
                       "verdict).")
    plunges_into_material: int = Field(
        0, description="Feed moves of the roughing end mill straight down (within 10 degrees of the tool axis) that "
                       "removed material: plunges into solid stock (reported; not part of the verdict).")
    over_engagement_moves: int = Field(
        0, description="Level feed moves of the roughing end mill over paths.roughing.max_engagement_deg (reported; "
                       "not part of the verdict).")
    operations: list[OperationFigures] = Field(
        default_factory=list, description="The program's moves per tool (roughing first), as the simulation ran them.")
    deviation: DeviationFigures | None = None
    finish: FinishFigures | None = Field(None, description="The area's points, measured exactly from every area's "
                                                           "finishing moves.")


class Verification(_Out):
    """The posted programs run on a simulated machine and stock (planning/simulate/, docs/programs.md)."""

    status: Literal["passed", "failed", "skipped"] = Field(
        ..., description="'passed' only when collisions, rapids into material, travel excursions, rotary feed "
                         "excesses and gouges beyond the tolerance are all zero; 'skipped' when simulate.enabled is false or nothing was posted.")
    message: str = Field(..., description="One line per class of offence, or why it passed or was skipped.")
    dialect: str | None = None
    resolution_mm: float | None = None
    stock_box_mm: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    stock_volume_mm3: float | None = None
    measuring_bound_mm: float | None = Field(None, description="Stated accuracy of the deviation figures, mm.")
    areas: list[AreaVerification] = Field(default_factory=list, description="In the order the set-ups run.")
    deviation: DeviationFigures | None = None
    finish: FinishFigures | None = Field(None, description="The whole scan, measured exactly from the finishing "
                                                           "moves (null: simulate.exact_finish is false).")
    rapids_into_material: int = 0
    holder_collisions: int = 0
    fixture_collisions: int = 0
    travel_excursions: int = 0
    rotary_feed_excesses: int = Field(0, description="Summed over the areas (AreaVerification).")
    plunges_into_material: int = 0
    over_engagement_moves: int = Field(0, description="Summed over the areas (AreaVerification).")
    unreadable_programs: int = Field(0, description="Programs the reader refused (named in notes): not verified.")
    machining_time_s: float = 0.0
    worst: list[VerificationOffence] = Field(default_factory=list, description="The worst offences of each class.")
    notes: list[str] = Field(default_factory=list, description="What the simulation assumed.")
    mode: Literal["single_pass", "independent"] | None = Field(
        None, description="'single_pass': the programs were proven to run the moves the paths stage simulated, "
                          "and that run's figures and stock were taken; 'independent': every program was run "
                          "again on a fresh stock (simulate.mode, or the single pass was not proven).")
    mode_note: str = Field("", description="What was proven, or why the programs were run again.")
    seconds: float = 0.0


class UnmachinedSummary(_Out):
    """Scan points no kept finishing move reaches (issue 16 item 3)."""

    n_points: int = Field(..., description="Input points not finished by any area's kept finishing moves.")
    share: float = Field(..., description="n_points / input points.")
    per_area: dict[int, int] = Field(default_factory=dict, description="Unmachined points per area.")
    message: str = Field("", description="Why, in one sentence.")


class AreaFigures(_Out):
    """One area's share of :class:`PlanFigures`: its input points by what became of them, and its time."""

    area: int = Field(..., description="Area (set-up) id.")
    n_points: int = Field(..., description="Input points of the area (the scan's points labelled with it).")
    finished: int | None = Field(None, description="Of those, finished within tolerance (simulation; null: not "
                                                   "simulated).")
    left: int | None = Field(None, description="Reached by a kept finishing move but not finished within "
                                               "tolerance (material left or cut below; null: not simulated).")
    unreached: int = Field(0, description="Not finished and reached by no kept finishing move (cut out for the "
                                          "holder, the stock, a fixture or the travel).")
    not_covered: int = Field(0, description="Not finished and seen by no chosen orientation (attached to the area "
                                            "by distance; no finishing is planned for them on purpose).")
    roughing_time_s: float | None = Field(None, description="Roughing machining time, s (see "
                                                            "PlanFigures.time_source).")
    semi_finishing_time_s: float | None = Field(None, description="Semi-finishing machining time, s (null: no "
                                                                  "semi-finishing; paths.semi_finishing).")
    finishing_time_s: float | None = Field(None, description="Finishing machining time, s.")
    machining_time_s: float = Field(0.0, description="The area's whole program, s.")


class PlanFigures(_Out):
    """The plan's figures, computed once (planning/report/figures.py) and read by the CLI summary, the plan's
    message, the service result, the pictures and the viewer. Every count is of INPUT points (the scan's
    points, or the points laid on a mesh's facets), not of the sampled points the set-ups were chosen on;
    each input point is in exactly one of finished, left, unreached, not_covered (checked in that order
    after finished: a point both unreached and not covered counts as not covered)."""

    counted_on: Literal["input points"] = "input points"
    n_points: int = Field(..., description="Input points.")
    measured: bool = Field(..., description="True when the finish was measured on the simulated stock "
                                            "(simulate.enabled); else finished and left are null.")
    finished: int | None = Field(None, description="Points within paths.finishing.tolerance_mm + scallop_mm (+ the "
                                                   "measuring bound) of the simulated final surface.")
    finished_share: float | None = Field(None, description="finished / n_points.")
    left: int | None = Field(None, description="Points reached by a kept finishing move, not finished within "
                                               "tolerance.")
    left_share: float | None = None
    unreached: int = Field(0, description="Points no kept finishing move reaches (not finished).")
    unreached_share: float = 0.0
    not_covered: int = Field(0, description="Points seen by no chosen orientation (not finished).")
    not_covered_share: float = 0.0
    target_coverage: float = Field(..., description="setups.coverage: the share the plan was asked to finish.")
    machining_time_s: float = Field(0.0, description="Whole plan, s: the programs as the control runs them when "
                                                     "simulated (each feed move at its program's F word, G93 "
                                                     "inverse time included, rapids at post.rapid_mm_min, no "
                                                     "acceleration), else the paths' estimate.")
    time_source: Literal["simulated", "estimate", "none"] = Field(
        "none", description="'simulated': machining_time_s from the posted programs as read back; 'estimate': from "
                            "the tool paths before posting (no tool changes or moves to the machine's Z0); 'none': "
                            "no paths.")
    areas: list[AreaFigures] = Field(default_factory=list, description="Per area, in machining order.")


Vec3Out = tuple[float, float, float]
PoseKind = Literal["as_scanned", "hull_face", "principal_axis"]


class PlacementCandidate(_Out):
    """One placement the search tried (planning/placement/, docs/design.md 'Placement')."""

    index: int = Field(..., ge=0, description="Order in which the candidates were listed.")
    kind: PoseKind
    label: str = Field(..., description="What it is, for the operator (e.g. 'resting on hull face 0').")
    up: Vec3Out = Field(..., description="The scanned-frame direction that points up once placed.")
    yaw_deg: float = Field(0.0, description="Extra turn about the vertical (only where the C axis is limited), deg.")
    stability_deg: float | None = Field(None, description="Hull faces: tipping angle, deg (larger is steadier).")
    part_height_mm: float = Field(..., description="Height of the placed part, mm.")
    stage: Literal["bound", "screened", "confirmed"] = Field(
        ..., description="How far it was evaluated: 'bound' = ruled out by the price bound on the pairs left by the "
                         "cone, travel, fixtures and table; 'screened' = set-ups chosen with the sampled points as the "
                         "only collision obstacles (a superset of the visible pairs); 'confirmed' = the plan's own "
                         "visibility and set-up stages.")
    feasible: bool | None = Field(
        None, description="Reaches setups.coverage with setups.max_setups set-ups: proven false at any stage, true only "
                          "when confirmed; null = not settled (screened feasible but not confirmed, or the set-up "
                          "search's time limit came first).")
    k: int | None = Field(None, description="Set-ups of the selection at the stage reached.")
    overlap: int | None = Field(None, description="Overlap points of that selection.")
    coverage: float | None = Field(None, description="Coverage of that selection (with max_setups set-ups where "
                                                     "infeasible: the best reachable at that stage).")
    coverage_bound: float | None = Field(
        None, description="Proven: no max_setups set-ups cover more than this fraction of the sampled points here.")
    seconds: float = Field(..., description="Time spent on this candidate, s.")


class PlacementSummary(_Out):
    """How the part is placed on the table (fixtures.placement): the rigid motion applied to the scan,
    ``placed = R @ scanned + t``, and with 'auto' the candidates tried. Everything else in the plan is in
    the placed frame."""

    mode: Literal["as_scanned", "auto"]
    kind: PoseKind = Field(..., description="The kind of placement used.")
    candidate: int | None = Field(None, description="Index of the chosen candidate in candidates (null: none tried).")
    label: str = Field(..., description="The placement used, for the operator.")
    rotation: tuple[Vec3Out, Vec3Out, Vec3Out] = Field(..., description="R (3x3, rows), applied to scanned points.")
    translation_mm: Vec3Out = Field(..., description="t, mm, added after the rotation.")
    n_candidates: int = Field(0, ge=0, description="Candidates tried.")
    candidates: list[PlacementCandidate] = Field(default_factory=list)
    screening: str = Field("", description="What the screening evaluated, and on which points.")
    seconds: float = Field(0.0, description="Time of the placement search, s.")
    message: str = Field("", description="One sentence on the outcome.")


class PathsSurface(_Out):
    """What the finishing ball rested on (paths.surface; planning/toolpath/surface.py)."""

    kind: Literal["points", "input_mesh", "scanner_grid", "reconstructed"] = Field(
        ..., description="'points': the scan points; 'input_mesh': the file's triangles; 'scanner_grid': triangles "
                         "from a structured scan's or a relief image's grid; 'reconstructed': ball-pivoting triangles "
                         "through the points.")
    n_triangles: int = Field(0, ge=0)
    spacing_mm: float = Field(..., description="Estimated mean point spacing, mm.")
    threshold_mm: float = Field(..., description="20 % of the tool radius: above it the points alone are too sparse, mm.")
    dip_on_points_mm: float = Field(..., description="How far a ball sinks between points that far apart, mm.")
    unmeshed_share: float = Field(0.0, description="Share of the points on no triangle.")
    reason: str = ""


class AdviceTry(_Out):
    """One change the planner tried on an infeasible plan (planning/advice.py): the visibility and set-up
    stages run again with it, on the same sampled points and normals (paths are not run)."""

    parameter: str = Field(..., description="The parameter changed, as `--set` names it (e.g. "
                                            "'fixtures.fixture_height_mm').")
    value: bool | int | float | str | list[float] = Field(
        ..., description="Its value in the try, as `--set` takes it, in the parameter's own unit (mm for *_mm, "
                         "degrees for *_deg, a count for setups.max_setups).")
    assignment: str = Field(..., description="The `--set` argument: parameter=value.")
    feasible: bool = Field(..., description="True when the set-up selection reached setups.coverage with at most "
                                            "setups.max_setups set-ups (of the try) with it.")
    coverage: float | None = Field(None, description="Fraction (0-1) of the sampled points the try's best selection "
                                                     "covers; null when the try gave no selection.")
    k: int | None = Field(None, description="Set-ups of that selection (a count).")
    seconds: float = Field(..., ge=0, description="Wall time of the try, s (the placement try: the placement "
                                                  "search the as-scanned hint ran, not counted in the budget).")
    note: str = Field("", description="What else the operator should know of this try (the placement found, a "
                                      "selection stopped by its time limit).")


class Advice(_Out):
    """What the planner tried after an infeasible set-up selection, in the fixed order of
    planning/advice.py, and the first change that reaches setups.coverage (null without one)."""

    target_coverage: float = Field(..., description="setups.coverage the tries had to reach, a fraction (0-1).")
    budget_s: float = Field(..., description="Time allowed for the tries, s (planning.advice.ADVICE_BUDGET_S); no try "
                                             "starts after it is spent, nor one running the visibility stage when "
                                             "less is left than the plan's own visibility stage took.")
    seconds: float = Field(..., ge=0, description="Wall time of the tries together, s.")
    tries: list[AdviceTry] = Field(default_factory=list, description="The tries, in the order run; they stop at "
                                                                     "the first feasible one.")
    not_tried: list[str] = Field(default_factory=list, description="Changes of the order left out, each "
                                                                   "'parameter=value (why)'.")
    budget_spent: bool = Field(False, description="True when the time budget ran out before every change was tried.")
    chosen: int | None = Field(None, description="Index in tries of the first change that reaches the coverage; "
                                                 "null when none does.")
    closest: int | None = Field(None, description="When none does: index in tries of the try with the highest "
                                                  "coverage (first of equals).")
    command: str | None = Field(None, description="The command line to plan with the chosen change: the `scanmill "
                                                  "plan` command as given, the same --set replaced, plus the change; "
                                                  "null outside the command line (set the parameter in the job's "
                                                  "parameters instead).")
    message: str = Field("", description="The sentence the plan's message carries.")


class PlanResult(_Out):
    """Everything ``scanmill plan`` and a finished job report about a plan."""

    schema_version: Literal["1.0"] = SCHEMA_VERSION
    scanmill_version: str
    status: Literal["planned", "unfinished", "infeasible", "incomplete"] = Field(
        ..., description="'planned': the set-ups reach setups.coverage and, when simulated, the programs finish at "
                         "least that share of the scan (figures.finished_share); 'unfinished': the set-ups reach "
                         "the coverage but the simulated programs finish less of the scan (CLI exit status 5); "
                         "'infeasible': the coverage cannot be reached with max_setups; 'incomplete': the search "
                         "time limit ran out before the coverage was reached or ruled out. In the last two the "
                         "best set-ups found are still reported and segmented. Whether the programs are safe is "
                         "verification.status.")
    message: str = Field(..., description="One sentence for the operator.")
    input: InputSummary
    parameters: PlanConfig
    normals: NormalsSummary
    orientations: OrientationsSummary
    visibility: VisibilitySummary | None = None
    selection: Selection
    setups: list[Setup]
    coverage: float = Field(..., description="Fraction of sampled points seen by at least one chosen orientation.")
    overlap_points: int
    n_integrated: int = Field(..., description="Sampled points attached to an area by distance.")
    areas: AreasSummary | None = Field(None, description="Regions and seams of the areas together.")
    verification: Verification | None = Field(None, description="The programs run on a simulated machine and stock.")
    machining_order: list[int] = Field(
        default_factory=list, description="Set-up (area) ids in the order they are machined (paths.carry_stock: the "
                                          "stock is carried in this order; the programs run in it).")
    unmachined: UnmachinedSummary | None = Field(
        None, description="Scan points that no kept finishing move reaches (cut out for collisions or travel).")
    figures: PlanFigures | None = Field(
        None, description="The plan's figures, once: finished, left, unreached, not covered (input points) and "
                          "the machining time; every other report reads these.")
    placement: PlacementSummary | None = Field(
        None, description="How the part sits on the table (fixtures.placement) and, with 'auto', the placements tried.")
    advice: Advice | None = Field(
        None, description="An infeasible plan: the cheap changes tried on its visibility and set-up stages and the first "
                          "that reaches setups.coverage (planning/advice.py); null otherwise.")
    paths_surface: PathsSurface | None = Field(
        None, description="What the finishing ball rested on and the gouge clearance was measured to (null without "
                          "finishing paths).")
    timings: list[Timing]
    warnings: list[str]
    artifacts: Artifacts = Field(default_factory=Artifacts)


def plan_json_schema() -> dict:
    """The JSON Schema (draft 2020-12) that every ``plan.json`` validates against."""
    schema = PlanResult.model_json_schema(by_alias=True, mode="serialization")
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "scanmill plan"
    return schema
