"""`sandtrack repose IMAGE|VIDEO|FOLDER|DUMP [--json] [--plot PNG]`: the static angle of repose of a heap."""

from __future__ import annotations

from .common import Progress, add_json_flag, emit


def register(sub) -> None:
    p = sub.add_parser(
        "repose", help="angle of repose of a heap: side photo, video, folder, or DEM dump / exchange CSV",
        description="A side photo: the heap's silhouette, both flanks fitted on their straight middle part, angle "
                    "per flank and mean with the fit's uncertainty. A video: the angle over time and its settled "
                    "value. A DEM result (LIGGGHTS/LAMMPS dump, exchange CSV): the surface particles fitted in "
                    "radial slices, angle to the base plane per slice, mean and spread. A folder: each file.")
    p.add_argument("path", help="photo, video, folder, dump (a quoted glob for per-step files) or exchange CSV")
    g = p.add_argument_group("photos and videos")
    g.add_argument("--calibration", metavar="CAL.toml",
                   help="calibrated camera (world +Y up): undistorts and corrects perspective exactly")
    g.add_argument("--camera", help="camera of the calibration (default: the first)")
    g.add_argument("--scale-mm-per-px", type=float, metavar="S", help="image scale, for the heap's size in mm")
    g.add_argument("--side", choices=["left", "right", "both"], default="both", help="flanks to measure (both)")
    g.add_argument("--every", type=float, metavar="S", help="video: measure a frame every S seconds "
                   "(default: up to 120 frames spread over the video)")
    d = p.add_argument_group("DEM results")
    d.add_argument("--up", help="the DEM's up axis, e.g. z or -y (default: detected: the heap's thin direction)")
    d.add_argument("--dem-units", choices=["m", "cm", "mm"], help="length unit (default: from the data)")
    d.add_argument("--dt", type=float, help="DEM time step (s), for dumps without ITEM: TIME (else times are steps)")
    d.add_argument("--type", dest="types", help="particle types to keep, e.g. 1 or 1,2 (default: all)")
    d.add_argument("--slices", type=int, help="radial slices (default 16, fewer for a small heap: about 30 "
                   "surface particles in each)")
    p.add_argument("--band", default="0.2,0.8", metavar="LO,HI",
                   help="part of the heap's height fitted, from the base (default 0.2,0.8: toe and top left out)")
    p.add_argument("--plot", metavar="PNG", help="write a figure of the result")
    add_json_flag(p)
    p.set_defaults(func=run)


def parse_band(text: str) -> tuple[float, float]:
    from ..errors import SandtrackError

    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise SandtrackError(f"--band {text!r}: give two fractions LO,HI such as 0.2,0.8") from None
    if not 0.0 <= lo < hi <= 1.0 or hi - lo < 0.2:
        raise SandtrackError(f"--band {text!r}: need 0 <= LO < HI <= 1 and at least 0.2 apart")
    return lo, hi


def run(args) -> int:
    from ..camera import Calibration
    from ..errors import SandtrackError
    from ..repose import kind_of, measure_path, report

    band = parse_band(args.band)
    if args.scale_mm_per_px is not None and not args.scale_mm_per_px > 0:
        raise SandtrackError("--scale-mm-per-px must be positive")
    if args.every is not None and not args.every > 0:
        raise SandtrackError("--every must be positive")
    types = None
    if args.types:
        try:
            types = [int(v) for v in args.types.split(",")]
        except ValueError:
            raise SandtrackError(f"--type {args.types!r}: give whole numbers such as 1 or 1,2") from None
    calibration = Calibration.load(args.calibration) if args.calibration else None
    kind = kind_of(args.path)
    bar = Progress(1, f"repose {kind}") if kind in ("video", "folder", "dump") else None
    result = measure_path(args.path, side=args.side, band=band, calibration=calibration, camera=args.camera,
                          scale_mm_per_px=args.scale_mm_per_px, every_s=args.every, up=args.up,
                          units=args.dem_units, dt=args.dt, types=types, slices=args.slices,
                          progress=(lambda done, total: (setattr(bar, "total", max(total, 1)), bar.update(done)))
                          if bar else None)
    if bar:
        bar.close()
    out = report.to_dict(result)
    if args.plot:
        image = None
        if kind == "image":
            from ..repose.image import read_image

            image = read_image(args.path)
        out["plot"] = str(report.plot(result, args.plot, image))
    emit(out, args.json, text=report.text(result))
    return 0
