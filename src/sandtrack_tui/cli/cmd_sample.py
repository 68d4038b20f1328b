"""`sandtrack sample OUT_DIR [--seed N] [--preset small|full] [--variant NAME]`: render the rig's digital twin.

Writes calibration and experiment videos of both cameras (H.264 + AAC) and exact ground truth
(cameras, sync offset, marker XYZ/pixels/visibility, tool, board corners, DEM-style trajectories).
`--variant` renders one of the twin's harder tracking cases instead (twin/catalog.py): sand-box cases
(twin/variants.py) or the bedload flume (twin/flume.py).
"""

from __future__ import annotations

import argparse

from .common import add_json_flag, emit, log

# (twin/catalog.py VARIANTS, named here so the parser does not load the renderers)
VARIANT_NAMES = ("blue", "red", "white", "black", "glass", "light-sand", "dark-sand", "wet-sand", "dense", "fast",
                 "large", "shake", "dense300", "flume", "flume-8bit")


def register(sub) -> None:
    p = sub.add_parser(
        "sample",
        help="render the sample project (twin of the rig) with exact ground truth",
        description="Render the sand-box rig: calibration and experiment videos of the side and front cameras "
                    "plus ground truth. Deterministic for a seed.",
    )
    p.add_argument("out_dir", help="output folder (created if missing; files in it are overwritten)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--preset", choices=["small", "full", "tiny", "repose"], default="small",
                   help="small: 8.8 s experiment + 8 s calibration (the bundled sample_data); "
                        "full: same experiment + 42 s calibration (>= 44,130 two-view corner observations); "
                        "tiny: a few frames, for tests; "
                        "repose: heaps of known angle of repose, photos and DEM dumps, under OUT/repose/")
    p.add_argument("--variant", metavar="NAME",
                   help="render a tracking case instead of a preset: " + ", ".join(VARIANT_NAMES) +
                        " (marker styles, sand tones, dense identical beads, fast and blurred, large, shaken, "
                        "300 scattered markers, a bedload flume of glass beads in 16-bit TIFF or 8-bit PNG frames; "
                        "experiment videos or image folders and exact truth only)")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    add_json_flag(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..errors import SandtrackError
    from ..twin.sample import render_sample

    if args.workers < 1:
        raise SandtrackError("--workers must be at least 1")
    if args.variant is not None:
        from ..twin.catalog import render_variant

        result = render_variant(args.variant, args.out_dir, seed=args.seed, log=log)
        text = (f"rendered twin variant {args.variant} (seed {args.seed}) into {args.out_dir} in {result['render_s']} "
                f"s: {result['frames']} frames per camera ({', '.join(result['cameras'])}): "
                f"{result['note'] or result['style'] + ' markers on ' + result['sand'] + ' sand'}; "
                f"{result['render_cpu_s']} s CPU")
        emit(result, args.json, text)
        return 0
    result = render_sample(args.out_dir, seed=args.seed, preset=args.preset, workers=args.workers, log=log)
    if args.preset == "repose":
        text = (f"rendered the repose preset (seed {args.seed}) into {result['out_dir']}/repose in "
                f"{result['render_s']} s: {result['heaps']} files of known angle (ground_truth/repose.json), "
                f"{result['total_bytes'] / 1e6:.1f} MB")
        emit(result, args.json, text)
        return 0
    text = (
        f"rendered {args.preset} sample (seed {args.seed}) into {result['out_dir']} in {result['render_s']} s: "
        f"{result['experiment_frames']} experiment and {result['calibration_frames']} calibration frames per camera, "
        f"{result['two_view_corner_observations']} two-view corner observations, "
        f"{result['total_bytes'] / 1e6:.1f} MB"
    )
    emit(result, args.json, text)
    return 0
