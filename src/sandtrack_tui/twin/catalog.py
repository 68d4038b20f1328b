"""The twin's tracking cases (`sandtrack sample --variant NAME`), each rendered by its own renderer.

- sand-box cases (variants.py): the rig's sand box, tool and light through windows of the true
  cameras: marker styles, sand tones, crowds, speed, blur, shake;
- the bedload flume (flume.py): a backlit channel of glass beads seen side-on.

`CROWDS` are the cases with hundreds of identical beads, to be detected and linked everywhere rather
than seeded one by one. `cache_key(name)` names a render by what it depends on: the source its
renderer runs (source_hash) and the case's own settings; a new case, or a change to another
renderer, leaves the key of the others as it was.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, replace
from pathlib import Path

from ..errors import SandtrackError
from ..source_hash import source_hash
from .flume import Flume, render_flume
from .variants import Variant, render_sandbox

VARIANTS: dict[str, Variant | Flume] = {v.name: v for v in (
    Variant("blue", note="the sample's blue markers, 9 px, through a window"),
    Variant("red", style="red"),
    Variant("white", style="white"),
    Variant("black", style="black"),
    Variant("glass", style="glass", radius_mm=3.0, note="grey glass beads, 6 mm"),
    Variant("light-sand", style="blue", sand="light"),
    Variant("dark-sand", style="white", sand="dark"),
    Variant("wet-sand", style="red", sand="wet"),
    Variant("dense", style="black", layout="dense", radius_mm=3.0, zoom=1.25, speed_mm_s=200.0, output="tiff16",
            note="56 touching black 6 mm beads, 16-bit grey TIFF frames"),
    Variant("fast", style="blue", speed_mm_s=250.0, shutter=0.6,
            note="tool at 250 mm/s: markers up to ~25 px per frame, blurred over 0.6 of the frame time"),
    Variant("large", style="red", zoom=1.65, size=(640, 448), note="15 px markers"),
    Variant("shake", style="white", sand="dark", zoom=1.3, speed_mm_s=150.0, shutter=0.5, shake_px=1.5, pan_px=0.5,
            cameras=("side",), output="jpeg",
            note="pale 12 px markers on dark sand, blurred, hand-held camera panning 0.5 px per frame and shaking, "
                 "JPEG frames"),
    Variant("dense300", style="blue", layout="scattered", speed_mm_s=150.0, size=(640, 448), start_s=2.6,
            note="300 identical 5 mm blue markers scattered in and beside the tool's lane (some touching), "
                 "pushed by the tool"),
    Flume(note="bedload flume: ~330 black 6 mm glass beads (bright centres) in a backlit channel, 1280 x 320 px "
               "at 130 fps, rolling and saltating at up to ~25 px per frame, 16-bit grey TIFF frames"),
    Flume(name="flume-8bit", output="png8", note="the flume in 8-bit grey PNG frames"),
)}
CROWDS = ("dense300", "flume", "flume-8bit")
RENDERERS = {Variant: ("sandtrack_tui.twin.variants", render_sandbox),
             Flume: ("sandtrack_tui.twin.flume", render_flume)}


def variant_names() -> list[str]:
    return list(VARIANTS)


def get_variant(variant: str | Variant | Flume) -> Variant | Flume:
    if isinstance(variant, str):
        if variant not in VARIANTS:
            raise SandtrackError(f"unknown twin variant {variant!r} (one of {', '.join(VARIANTS)})")
        return VARIANTS[variant]
    return variant


def render_variant(variant: str | Variant | Flume, out_dir: str | Path, seed: int = 0, log=lambda msg: None) -> dict:
    """Render one case (a name of VARIANTS, or a case) into out_dir; returns what was written."""
    v = get_variant(variant)
    return RENDERERS[type(v)][1](v, out_dir, seed=seed, log=log)


def cache_key(variant: str | Variant | Flume) -> str:
    """Hash (10 hex digits) of what a case's render depends on: its renderer's source and its settings."""
    v = get_variant(variant)
    h = hashlib.sha1(source_hash(RENDERERS[type(v)][0]).encode())
    h.update(json.dumps(asdict(v), sort_keys=True, default=str).encode())
    return h.hexdigest()[:10]


def excerpt(name: str, start_s: float, frames: int, **changes) -> Variant:
    """A stretch of a sand-box case (tests): `frames` frames from scene time `start_s`, other fields changed."""
    return replace(get_variant(name), start_s=start_s, frames=frames, **changes)
