"""Which appearance model a seed box gets (appearance.py): the first of colour (colour.py), brightness
and texture (brightness.py) that clearly separates the marker from the sand around it.

A box with no contrast of any kind gives one line saying what was measured and what to do.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import SandtrackError
from . import brightness, colour
from .appearance import BRIGHT, DARK, MIN_SEPARATION, AppearanceModel, SeedPatch

# A colour model covering less than this share of the brightness model's marker area learned from the
# same box has found a part of the marker (a rim, a reflection), not the marker.
PART_OF_MARKER = 0.5


def learn(frame, cx: float, cy: float, w: float, h: float, centred: bool = True, kind: str | None = None,
          like: AppearanceModel | None = None) -> AppearanceModel:
    """Learn the appearance model of the marker in a seed box centred at (cx, cy), w x h px.
    `frame`: BGR or grey, 8 or 16 bit. `centred`: the box is centred on the marker (a seed), so a
    blob model must cover the box's centre (a box centred on a pattern, such as a corner between
    dark and light squares, gets a texture model, not the model of a blob beside its centre); not
    so for a box around a click that may be off the marker. `kind`: the brightness model (dark or
    bright) of a marker this one is like (auto-seed), tried first, against sand farther out when the
    ring around the box holds none (a bead inside a dense layer is surrounded by beads: against them
    only its highlight stands out); `like`: that marker's own model, taken as this one's when it was
    learned among touching lookalikes (the beads of one layer) or when even then its kind is not
    found. Raises SandtrackError with what was measured when the box holds nothing that stands out
    from the sand around it."""
    if like is not None and like.crowd and kind == like.kind:
        return replace(like)  # (touching lookalikes: the beads of one layer, learned once among them)
    if kind in (DARK, BRIGHT):
        for widen in (1.0, 2.0, 3.0):
            try:
                seed = SeedPatch.cut(frame, cx, cy, w, h, widen)
            except SandtrackError:
                break
            m, _ = brightness.learn_brightness(seed, -1.0 if kind == DARK else 1.0)
            if m is not None and (not centred or seed.centre_scores(m)):
                return m
        if like is not None and like.kind == kind:
            return replace(like)
    seed = SeedPatch.cut(frame, cx, cy, w, h)
    model, colour_sep = colour.learn_colour(seed)
    bright, bright_sep = brightness.learn_brightness(seed)
    if centred:
        model = model if model is None or seed.centre_scores(model) else None
        bright = bright if bright is None or seed.centre_scores(bright) else None
    grey = model is not None and colour.achromatic(seed, model)
    if model is not None and bright is not None and model.disc_area < PART_OF_MARKER * bright.disc_area:
        grey = True  # its colour is a part of the marker (a glass bead's rim): its brightness is the marker
    if bright is not None and (model is None or grey):
        return bright  # a white, grey or black marker: its brightness is what it is
    if model is not None and not grey:
        model.luma_follows = bright is not None
        return model
    texture = brightness.learn_texture(seed)
    if texture is not None and (model is None or brightness.two_tone(seed)):
        return texture
    if model is not None:  # a grey marker on coloured sand, its shaded side as bright as the sand
        model.luma_follows, model.grey = False, True
        return model
    lum_in, lum_ring = seed.luma[seed.inner], seed.luma[seed.ring]
    seps = ", ".join(f"{what} separation {v:.2f}" for what, v in (("colour", colour_sep), ("brightness", bright_sep))
                     if np.isfinite(v))
    raise SandtrackError(
        f"no marker found in the {w:.0f}x{h:.0f} px seed box: nothing in it stands out from the sand around it "
        f"(luma {np.median(lum_in):.0f}±{_spread(lum_in):.0f} inside, {np.median(lum_ring):.0f}±"
        f"{_spread(lum_ring):.0f} around{'; ' + seps if seps else ''}; {MIN_SEPARATION} needed); centre a larger "
        f"box on the marker (about twice its size), or seed it in another frame where it stands out")


def _spread(v: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(v - np.median(v)))) if len(v) else float("nan")
