"""The end of an every-particle run: pieces of one particle's track joined across short gaps (gaps.py) in
each camera, then the tracks of two calibrated cameras paired across the views (particle_pairs.py), each
particle made one marker, in the run's own edit (one undo takes back the run, joins included).

A joined particle keeps the id of its first piece (for a pair: of its first piece in the first camera); the
other pieces' points move to it (corrections.merge_in_edit) and the frames between two pieces are flagged
`occluded` (the coasting prediction where the tracker made one, else no position).
"""

from __future__ import annotations

import numpy as np

from ..corrections import merge_in_edit
from . import gaps
from .particle_pairs import pair_tracks


def join_tracks(project, ed, runs: dict, run_ids: set, gap_closing: bool = True, pairing: bool = True,
                max_gap: int = gaps.MAX_GAP_FRAMES) -> dict:
    """runs: camera -> (first frame, last frame, particle diameter px) of this run; run_ids: the markers it
    wrote. Returns the summary: per camera `gaps_closed` (pieces joined) and `gaps_left_apart`, and the
    pairing across the views (`paired`, `pair_pieces_joined`, `unpaired_ambiguous`, `unpaired_alone`)."""
    cams = list(runs)
    pts = project.points()
    pts = pts[pts.camera.isin(cams) & pts.marker.isin(list(run_ids))]
    out: dict = {"gaps": {}, "pairing": None}
    # the operator's seeded particle is already one marker in both views: it is joined, never re-paired
    both = set(pts.groupby("marker").camera.nunique().loc[lambda s: s > 1].index)
    chains: dict[str, list[list[int]]] = {}
    for c in cams:
        f0, last, diameter = runs[c]
        if gap_closing:
            joins, apart = gaps.find_joins(pts[pts.camera == c], diameter, f0, last, max_gap)
        else:
            joins, apart = [], 0
        chains[c] = gaps.chains(joins)
        out["gaps"][c] = {"gaps_closed": len(joins), "gaps_left_apart": apart}
    head = {(c, int(m)): ch[0] for c in cams for ch in chains[c] for m in ch}
    pieces = {(c, ch[0]): ch for c in cams for ch in chains[c]}
    groups = []  # [{camera: [pieces in time order]}]
    grouped = set()
    cal = project.calibration() if pairing and len(cams) == 2 else None
    if cal is not None and all(c in cal.cameras for c in cams):
        from ..xyz import Timeline

        joined = pts.assign(marker=[head.get((c, int(m)), int(m)) for c, m in zip(pts.camera, pts.marker,
                                                                                      strict=True)])
        result = pair_tracks(joined[~joined.marker.isin(list(both))], cal, (cams[0], cams[1]),
                             Timeline.from_project(project))
        for g in result.groups:
            groups.append({c: [p for h in g[c] for p in pieces.get((c, h), [h])] for c in g})
            grouped |= {(c, h) for c in g for h in g[c]}
        out["pairing"] = {"paired": len(result.groups),
                          "pair_pieces_joined": sum(len(g[c]) - 1 for g in result.groups for c in g),
                          "unpaired_ambiguous": {c: len(v) for c, v in result.ambiguous.items()},
                          "unpaired_alone": {c: len(v) for c, v in result.lonely.items()}}
    for c in cams:
        groups += [{c: ch} for ch in chains[c] if (c, ch[0]) not in grouped]
    merges, writes, deletes = [], [], []
    by_marker = {c: gaps.pieces_of(pts[pts.camera == c]) for c in cams}
    meas = pts[pts.status.isin(gaps.MEASURED) & pts.x_px.notna()]
    first = {c: meas[meas.camera == c].groupby("marker").frame.min().to_dict() for c in cams}
    for g in groups:
        keep = g[cams[0]][0] if cams[0] in g else next(iter(g.values()))[0]
        for c, ids in g.items():
            ordered = sorted(ids, key=lambda m, c=c: (first[c].get(m, np.inf), m))
            w, d = gaps.gap_rows(by_marker[c], ordered, c)
            writes += w
            deletes += d
            merges += [(keep, m) for m in ordered if m != keep]
    if writes:
        ed.write(writes)
    if deletes:
        ed.delete(deletes)
    if merges:
        merge_in_edit(project, ed, merges)
    out["tracks_before"] = {c: int(pts[pts.camera == c].marker.nunique()) for c in cams}
    out["merged_away"] = len(merges)
    return out
