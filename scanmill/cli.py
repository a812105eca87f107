"""The ``scanmill`` command line: plan a scan, write reference samples, print schemas and profiles, warm up.

Exit status: 0 planned (and, when simulated, the programs verified safe and finishing at least
``setups.coverage`` of the scan); 2 bad input or parameters (a message says what to fix); 3 planned but
infeasible or incomplete (no ``setups.max_setups`` orientations reach ``setups.coverage``, or the
search time limit ran out first; the best plan found is still written); 4 the verification failed (a
program would harm the machine, the tool or the part); 5 status 'unfinished': the set-ups reach the
coverage and the programs are safe, but they finish less than ``setups.coverage`` of the scan
(plan.json ``figures``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import scanmill
from planning.errors import PlanningError

EXIT_OK, EXIT_ERROR, EXIT_INFEASIBLE, EXIT_UNSAFE, EXIT_UNFINISHED = 0, 2, 3, 4, 5


class _Progress:
    """Prints one line per stage start/end and progress inside long stages, to stderr: a line when
    the stage has moved on by a fifth, or when the next report, expected as far off as this one came
    after the one before, would come more than ``every_s`` (2 s) after the stage's last line (so a
    stage that reports every 1.5 s prints every report, one that reports ten times a second a line
    about every 2 s: the lines are never further apart than the reports or ``every_s``)."""

    def __init__(self, stream=None, quiet: bool = False, every_s: float = 2.0):
        self.stream, self.quiet, self.every_s = stream, quiet, float(every_s)
        self._last: dict[str, tuple[float, float]] = {}
        self._call: dict[str, float] = {}
        self._t0 = time.perf_counter()

    def __call__(self, stage: str, fraction: float, message: str) -> None:
        if self.quiet:
            return
        now = time.perf_counter()
        last, last_t = self._last.get(stage, (-1.0, -float("inf")))
        gap = now - self._call.get(stage, now)             # since this stage's previous report
        self._call[stage] = now
        if 0.0 < fraction < 1.0 and fraction - last < 0.2 and now - last_t + gap < self.every_s:
            return
        self._last[stage] = (fraction, now)
        elapsed = now - self._t0
        print(f"[{elapsed:7.2f} s] {stage:<12} {fraction:4.0%}  {message}", file=self.stream or sys.stderr,
              flush=True)


def _load_config(args) -> dict:
    from schemas.params import apply_overrides
    data: dict = {}
    if args.config:
        try:
            data = json.loads(Path(args.config).read_text())
        except FileNotFoundError:
            raise PlanningError(f"configuration file not found: {args.config}", code="invalid_parameter")
        except json.JSONDecodeError as exc:
            raise PlanningError(f"configuration file {args.config} is not valid JSON: {exc}",
                                code="invalid_parameter")
    return apply_overrides(data, args.set or [])


def _summary_table(result) -> str:
    rows = [("set-up", "tool axis (x, y, z)", "phi/theta deg", "rotary deg", "visible", "points", "integrated",
             "regions (min)", "largest", "seam mm")]
    for s in result.setups:
        rot = " ".join(f"{k}{v:+.1f}" for k, v in s.rotary_deg.items())
        g = s.regions
        reg = (f"{g.n_regions} ({g.min_regions})", f"{g.largest_region_share:.0%}", f"{g.seam_mm:.0f}") if g else ("", "", "")
        rows.append((str(s.id), "({:+.3f}, {:+.3f}, {:+.3f})".format(*s.tool_axis),
                     f"{s.phi_deg:.0f}/{s.theta_deg:.0f}", rot, str(s.n_visible), str(s.n_points),
                     str(s.n_integrated)) + reg)
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _paths_table(result) -> str:
    """One line per area with tool paths: finishing passes, moves, arcs, clearance, programs."""
    out = []
    for s in result.setups:
        p = s.path
        if p is None:
            continue
        parts = [f"area {s.id}:"]
        if p.roughing is not None:
            left = (f" ({p.roughing.n_pieces_left} pieces, {p.roughing.left_length_mm / 1000:.1f} m, left to the "
                    f"levels below: no helix or ramp fits)" if p.roughing.n_pieces_left else "")
            parts.append(f"roughing {p.roughing.n_levels} levels, {p.roughing.length_mm / 1000:.1f} m{left};")
        if p.finishing is not None:
            f = p.finishing
            parts.append(f"finishing {f.n_passes} passes, {f.n_cl} moves ({f.n_arcs} arcs), "
                         f"{f.length_mm / 1000:.1f} m, min clearance "
                         f"{f.min_clearance_mm:.4f} mm ({'gouge free' if f.gouge_free else 'GOUGES'});")
        parts.append(", ".join(list(p.programs.values()) + [m for m in (p.moves, p.moves_npz) if m]))
        out.append(" ".join(parts))
    return "\n".join(out)


def _print_verification(r) -> None:
    """What the simulation found: the worst offenders and the deviation (the verdict itself is in the
    machining summary, scanmill/summary.py)."""
    v = r.verification
    if v is None or v.status == "skipped" or not (v.worst or v.deviation is not None):
        return
    print("verification details (simulated machine):")
    shown: dict[str, int] = {}
    for o in v.worst:
        shown[o.kind] = shown.get(o.kind, 0) + 1
        if shown[o.kind] > 2:
            continue
        print(f"  {o.kind}: {o.program} line {o.line} at ({o.position_mm[0]:.2f}, {o.position_mm[1]:.2f}, "
              f"{o.position_mm[2]:.2f}) {o.amount:.3f} {o.detail}")
    if v.deviation is not None:
        d = v.deviation
        print(f"  deviation from the scan: {d.finished_share:.1%} finished within tolerance; material left p50 "
              f"{d.left_p50_mm:.3f}, p95 {d.left_p95_mm:.3f}, max {d.left_max_mm:.3f} mm; deepest cut below "
              f"the scan {d.gouge_max_mm:.3f} mm; simulated machining {v.machining_time_s / 60:.0f} min "
              f"(resolution {v.resolution_mm} mm, {r.artifacts.deviation_png})")
    if v.finish is not None:
        f = v.finish
        print(f"  finish, measured exactly from the finishing moves: {f.finished_share:.1%} within "
              f"{f.limit_mm:.3f} mm of the ball's surface ({f.reached_share:.1%} reached); material left over the "
              f"reached points p50 {f.left_p50_mm:.3f}, p95 {f.left_p95_mm:.3f}, max {f.left_max_mm:.3f} mm; "
              f"scallop p95 {f.scallop_p95_mm:.4f} mm; deepest below the scan {f.below_max_mm:.3f} mm")


def cmd_plan(args) -> int:
    from planning.inputs.cloud import read_input
    from planning.pipeline import run_plan
    from planning.report.plan_files import write_plan
    from scanmill.summary import format_summary
    from schemas.params import parse_config

    config = parse_config(_load_config(args))
    progress = _Progress(quiet=args.quiet)
    progress("read", 0.0, str(args.input))
    with warnings.catch_warnings():
        # what a reader changed is in cloud.warnings (printed with the plan's); a library's own warning
        # lines (numpy, Pillow, laspy) would only stand before an `error [code]` line or the summary
        warnings.simplefilter("ignore")
        cloud = read_input(args.input, config.input, fmt=args.format)
    progress("read", 1.0, f"{cloud.points.shape[0]} points ({cloud.source_format})")
    base_dir = Path(args.config).resolve().parent if getattr(args, "config", None) else Path.cwd()
    outcome = run_plan(cloud, config, name=Path(args.input).name, progress=progress, base_dir=base_dir,
                       command_line=getattr(args, "command_line", None))
    progress("write", 0.0, str(args.out))
    paths = write_plan(outcome, args.out, progress=lambda f, m: progress("write", f, m))
    progress("write", 1.0, "done")
    r = outcome.result
    print(r.message)
    planned = r.input.n_points_planned or r.input.n_points     # a mesh is planned on points laid on its facets
    mesh = (f" ({r.input.n_points} vertices, {r.input.n_faces} triangles, points laid "
            f"{r.input.facet_spacing_mm:g} mm apart)" if r.input.n_points_planned else "")
    print(f"sampled points {r.normals.n_sampled} of {planned}{mesh}; candidate axes "
          f"{r.orientations.n_machine_feasible} within machine travel; coverage {r.coverage:.1%}; "
          f"overlap {r.overlap_points} sampled points; {r.n_integrated} sampled points seen by no chosen "
          f"set-up attached to an area")
    if r.areas is not None:
        print(f"areas ({r.areas.method}): {r.areas.n_regions} regions, seams {r.areas.seam_mm:.0f} mm, "
              f"{r.areas.label_change_share:.1%} of neighbour pairs change area; regions (min) = regions "
              f"(at least this many forced by the visibility)")
    print(_summary_table(r))
    paths_text = _paths_table(r)
    if paths_text:
        print(paths_text)
    _print_verification(r)
    print(format_summary(r.model_dump(mode="json", by_alias=True)))
    for w in r.warnings:
        print(f"warning: {w}")
    print("timings: " + ", ".join(f"{t.stage} {t.seconds:.2f} s" for t in r.timings))
    print(f"wrote {len(paths)} files into {args.out}: {', '.join(p.name for p in paths.values())}")
    return exit_status(r)


def exit_status(r) -> int:
    """The exit status of a plan (module docstring): an unsafe verdict first, then infeasible or
    incomplete, then unfinished."""
    if r.verification is not None and r.verification.status == "failed":
        return EXIT_UNSAFE
    if r.status in ("infeasible", "incomplete"):
        return EXIT_INFEASIBLE
    return EXIT_UNFINISHED if r.status == "unfinished" else EXIT_OK


def cmd_sample(args) -> int:
    from planning.errors import ParameterError
    from planning.inputs.samples import RANGE_SHAPES, make_sample
    from planning.report.files import write_ply

    name = args.name
    if args.scanner == "range" and name not in ("range_scan", *RANGE_SHAPES.values()):
        if name not in RANGE_SHAPES:
            raise ParameterError(f"--scanner range: no range scan of {name!r}; it scans {', '.join(RANGE_SHAPES)}",
                                 parameter="scanner", value=name, allowed=list(RANGE_SHAPES))
        name = RANGE_SHAPES[name]
    kwargs = {}
    if args.points is not None:
        kwargs["n_points"] = args.points
    if args.seed is not None:
        kwargs["seed"] = args.seed
    if args.along_mm is not None:
        kwargs["along_mm"] = args.along_mm
    if args.across_mm is not None:
        kwargs["across_mm"] = args.across_mm
    s = make_sample(name, **kwargs)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_ply(out, s.points, normals=s.normals, binary=not args.ascii)
    print(f"wrote {out}: {s.name}, {s.points.shape[0]} points{' with exact normals' if s.normals is not None else ''}"
          f" - {s.description}")
    return EXIT_OK


def cmd_schema(args) -> int:
    if args.what == "plan":
        from schemas.plan import plan_json_schema
        schema = plan_json_schema()
    else:
        from schemas.params import PlanConfig
        schema = PlanConfig.model_json_schema(by_alias=True)
    print(json.dumps(schema, indent=2))
    return EXIT_OK


def cmd_profiles(args) -> int:
    from planning.orientations.kinematics import available_profiles, load_profile
    for name in available_profiles():
        p = load_profile(name)
        print(f"{name}: {p.kinematics} - {p.description}")
    return EXIT_OK


def cmd_warmup(args) -> int:
    from planning.warmup import WARMUP_SAMPLE, warm

    rep = warm(progress=_Progress(quiet=not args.verbose))
    if rep.n_compiled == 0:
        print(f"warmup: planned the {WARMUP_SAMPLE} sample in {rep.seconds:.1f} s; every kernel came from the "
              f"numba cache (nothing compiled)")
    else:
        print(f"warmup: planned the {WARMUP_SAMPLE} sample in {rep.seconds:.1f} s; compiled {rep.n_compiled} kernel "
              f"signature(s) of {len(set(rep.compiled))} kernel(s) that were not in the numba cache (cached now)")
    print(f"numba cache: {rep.cache_dir}  threading layer: {rep.threading_layer}")
    if args.list:
        for name in sorted(set(rep.compiled)):
            print(f"  compiled {name}")
    return EXIT_OK


def cmd_serve(args) -> int:
    from scanmill.serve import serve
    return serve(host=args.host, port=args.port, data_dir=args.data_dir, workers=args.workers,
                 config=args.config, log_level=args.log_level)


def cmd_view(args) -> int:
    from scanmill.viewer.local import view
    return view(args.plan_dir, host=args.host, port=args.port, open_browser=args.open)


def cmd_worker(args) -> int:
    from scanmill.worker import run_worker
    return run_worker(concurrency=args.concurrency, name=args.name, config=args.config, log_level=args.log_level)


def cmd_db(args) -> int:
    from scanmill.worker import upgrade_database
    return upgrade_database(args.config)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="scanmill", description=__doc__.splitlines()[0])
    ap.add_argument("--version", action="version", version=f"scanmill {scanmill.__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("plan", help="plan the 3+2 set-ups of a scan and write plan.json, plan.npz, PLY, PNG")
    p.add_argument("input", help="the scan: PLY (ascii/binary, faces kept), PCD, XYZ/CSV/TXT, STL, OBJ, LAS/LAZ, "
                                 "E57, or a PNG/JPEG/BMP/TIFF image read as a relief (input.relief)")
    p.add_argument("--config", help="plan configuration JSON (docs/design.md parameter names)")
    p.add_argument("--set", action="append", metavar="PATH=VALUE",
                   help="override one parameter, e.g. --set setups.coverage=0.9 (value parsed as JSON)")
    p.add_argument("--out", required=True, help="output directory")
    from planning.inputs.cloud import FORMATS
    p.add_argument("--format", choices=FORMATS, help="input format (default: detect)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_plan)

    s = sub.add_parser("sample", help="write a reference cloud (docs/design.md reference cases) as PLY")
    s.add_argument("name", help="half_sphere, femur_like, slot, post_wall, filleted_box, draft_slot; range scans: "
                                "range_femur, range_half_sphere, range_slot, range_filleted_box")
    s.add_argument("--out", required=True, help="output PLY file")
    s.add_argument("--points", type=int, help="number of points, where the sample takes one")
    s.add_argument("--seed", type=int, help="random seed")
    s.add_argument("--ascii", action="store_true", help="write ascii PLY instead of binary")
    s.add_argument("--scanner", choices=["uniform", "range"], default="uniform",
                   help="uniform: points drawn over the surface (default); range: a simulated range scan in scan "
                        "lines (femur_like, half_sphere, slot, filleted_box; the part scaled to --points)")
    s.add_argument("--along-mm", type=float, help="range scan: point spacing along the scan lines (0.3 mm)")
    s.add_argument("--across-mm", type=float, help="range scan: spacing between the scan lines (0.6 mm)")
    s.set_defaults(func=cmd_sample)

    c = sub.add_parser("schema", help="print the JSON Schema of plan.json or of the configuration")
    c.add_argument("what", choices=["plan", "config"], nargs="?", default="plan")
    c.set_defaults(func=cmd_schema)

    m = sub.add_parser("profiles", help="list the bundled machine profiles")
    m.set_defaults(func=cmd_profiles)

    u = sub.add_parser("warmup", help="compile the numba kernels into the cache now (a small plan), so the first "
                                      "plan does not compile them (cache: SCANMILL_CACHE_DIR)")
    u.add_argument("--verbose", action="store_true", help="progress lines of the warm-up plan")
    u.add_argument("--list", action="store_true", help="list the functions compiled")
    u.set_defaults(func=cmd_warmup)

    v = sub.add_parser("serve", help="run the planning service (HTTP jobs API, docs/service.md)")
    v.add_argument("--host", help="address to bind (default 127.0.0.1; SCANMILL_HOST)")
    v.add_argument("--port", type=int, help="TCP port (default 8000; SCANMILL_PORT)")
    v.add_argument("--data-dir", help="job store and files (default ./scanmill-data; SCANMILL_DATA_DIR)")
    v.add_argument("--workers", type=int, help="jobs run at once (SCANMILL_WORKERS)")
    v.add_argument("--config", help="settings file, TOML or JSON (SCANMILL_CONFIG)")
    v.add_argument("--log-level", choices=["critical", "error", "warning", "info", "debug"])
    v.set_defaults(func=cmd_serve)

    vw = sub.add_parser("view", help="show a plan directory in the browser viewer (serves it on 127.0.0.1 and "
                                     "prints the address to open)")
    vw.add_argument("plan_dir", help="a directory `scanmill plan` wrote (it holds viewer.json)")
    vw.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    vw.add_argument("--port", type=int, default=0, help="TCP port (default: a free one)")
    vw.add_argument("--open", action="store_true", help="also open the address in the default browser")
    vw.set_defaults(func=cmd_view)

    w = sub.add_parser("worker", help="run a Celery worker for the distributed backend (SCANMILL_BROKER_URL)")
    w.add_argument("--concurrency", type=int, help="jobs run at once on this machine (SCANMILL_WORKERS)")
    w.add_argument("--name", help="Celery node name (default scanmill-PID@HOST)")
    w.add_argument("--config", help="settings file, TOML or JSON (SCANMILL_CONFIG)")
    w.add_argument("--log-level", choices=["critical", "error", "warning", "info", "debug"])
    w.set_defaults(func=cmd_worker)

    d = sub.add_parser("db", help="job database maintenance (SCANMILL_DATABASE_URL)")
    d.add_argument("action", choices=["upgrade"], help="upgrade: create or migrate the schema to the newest")
    d.add_argument("--config", help="settings file, TOML or JSON (SCANMILL_CONFIG)")
    d.set_defaults(func=cmd_db)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # the command line as the user ran it: the advice of an infeasible plan prints it with its change
    args.command_line = [sys.argv[0]] + sys.argv[1:] if argv is None else ["scanmill"] + list(argv)
    try:
        return args.func(args)
    except PlanningError as exc:
        print(f"error [{exc.code}]: {exc.message}", file=sys.stderr)
        return EXIT_ERROR
    except MemoryError:
        # the readers bound their work by the header and the limits; this is the net under them and under the
        # stages: no traceback, one line that says what to change
        print("error [too_large_for_memory]: this machine has not enough memory for this input with these "
              "parameters; decimate the scan, lower input.max_points / input.max_faces / input.relief.max_pixels, "
              "or coarsen orientations.phi_step_deg / theta_step_deg", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
