"""The honesty checks across the views: a marker's points in the two cameras lie on each other's epipolar
lines (stereo.py), or one of them is not the marker."""

from __future__ import annotations

import numpy as np

from .trackset import TrackSet


def stereo_check(trackset: TrackSet, frames, props, forced, only_reattached: bool, flags: list,
                 max_events: int = 500) -> None:
    """A marker's proposals in the two views must lie on each other's epipolar lines (within the stereo
    threshold): where they do not, the suspect view (the proposal farther from its prediction, among those
    re-attached this step when `only_reattached`) is dropped and flagged (into `flags`). The operator's
    points are never dropped."""
    stereo = trackset.stereo
    a, b = stereo.cams
    if a not in frames or b not in frames:
        return
    pairs, pas, pbs = [], [], []
    for ka, kb in trackset.stereo_pairs(a, b):
        if only_reattached and not ((ka in props and props[ka].reattach) or (kb in props and props[kb].reattach)):
            continue
        pa, pb = trackset.point_at(ka, frames, props, forced), trackset.point_at(kb, frames, props, forced)
        if pa is None or pb is None:
            continue
        pairs.append((ka, kb))
        pas.append(pa)
        pbs.append(pb)
    if not pairs:
        return
    dist = stereo.distance(a, np.array(pas), b, np.array(pbs))  # one call for all markers
    for (ka, kb), d in zip(pairs, dist, strict=True):
        if d <= stereo.threshold_px:
            continue
        cands = [k for k in (ka, kb) if k in props and k not in forced]
        if only_reattached:
            cands = [k for k in cands if props[k].reattach] or cands
        if not cands:
            continue
        suspect = max(cands, key=lambda k: props[k].match.d2 if np.isfinite(props[k].match.d2) else 0.0)
        del props[suspect]
        if len(flags) < max_events:
            flags.append({"marker": suspect[0], "camera": suspect[1],
                                      "frame": int(frames[suspect[1]][0]), "epipolar_px": round(float(d), 2)})

