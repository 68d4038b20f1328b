"""Touching lookalikes seeded in one view each, paired across the views by their tracks and made one
marker (tracking/run.py `_merge_pairs`, CrowdPairing.pair's rule): how right the pairs are on the
twin's dense layer (twin/variants.py `dense`), seeded as bench_variants.py seeds it.

1. As seeded: the pairs made, how many join two different true beads, and the XYZ of the merged
   markers against the truth (bench_variants.score_3d).
2. The rule's reach when a bead's counterpart is not tracked: for each bead paired in 1, the same run
   with that bead's side marker removed after seeding (as when auto-seed does not find it in the
   side view): the pairs made then, and how many join two different true beads (its front track's
   bead with a lookalike beside it on the line).
3. Re-tracked from a later frame (as after a correction, `track --from N`) once the first run merged
   its pairs: the whole variant's figures (bench_variants' scoring) and the XYZ after the second run.

`python benchmarks/bench_pairing.py` prints one JSON line per run and a summary.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_variants as bv  # noqa: E402
from sandtrack_tui.camera import Calibration  # noqa: E402
from sandtrack_tui.groundtruth import identity_switches, match_marker_ids, score_tracking  # noqa: E402
from sandtrack_tui.store import Project  # noqa: E402
from sandtrack_tui.tracking.run import track_project  # noqa: E402
from sandtrack_tui.xyz import compute_xyz  # noqa: E402


def run(without_side_of: int | None = None, again_from: int | None = None) -> dict:
    """One tracking run of the dense variant; `without_side_of`: the true bead whose side marker is
    removed after seeding; `again_from`: then tracked again from that frame on (figures after both)."""
    folder = bv.ensure_variant("dense")
    info = json.loads((folder / "variant.json").read_text())
    cams = list(info["cameras"])
    videos = {c: folder / info["videos"][c] for c in cams}
    truth = bv._truth(folder, cams)
    with tempfile.TemporaryDirectory() as tmp:
        proj = Project.create(Path(tmp) / "v.sandtrack", videos)
        proj.set_calibration(Calibration.load(folder / "ground_truth" / "cameras.toml"))
        proj.set("sync_offset_s", 0.0)
        bv._seed(proj, videos, truth)
        seeded = proj.points()
        bead = {}  # (camera, marker) -> true bead, from the seeds
        for cam in cams:
            at = seeded[seeded.camera == cam]
            bead.update({(cam, m): b for m, b in match_marker_ids(at, SimpleNamespace(markers=truth)).items()})
        if without_side_of is not None:
            proj.delete_marker(next(m for (c, m), b in bead.items() if c == "side" and b == without_side_of))
        summary = track_project(proj)
        ids = match_marker_ids(proj.points(), SimpleNamespace(markers=truth))
        if again_from is not None:
            again = track_project(proj, start=again_from)
        points = proj.points()
        xyz = compute_xyz(proj, method="triangulation")
        proj.close()
    pairs = [(p["marker"], p["from"], bead.get(("side", p["marker"])), bead.get(("front", p["from"])),
              p["frame"], p["frames_on_line"]) for p in summary["paired_across_views"]]
    out = {"without_side_of_bead": without_side_of, "again_from": again_from, "pairs": len(pairs),
           "wrong": [dict(zip(("marker", "from", "side_bead", "front_bead", "frame", "frames_on_line"), p,
                              strict=True)) for p in pairs if p[2] != p[3]],
           "paired_beads": sorted(p[2] for p in pairs if p[2] == p[3])}
    t = SimpleNamespace(markers=truth)
    if again_from is not None:
        out.update(score_tracking(points, t, ids), **identity_switches(points, t, ids),
                   pairs_again=len(again["paired_across_views"]), stereo_flags_again=len(again["stereo_flags"]))
    out.update(bv.score_3d(xyz, points, truth, ids))
    return out


if __name__ == "__main__":
    base = run()
    print(json.dumps(base), flush=True)
    rows = [run(b) for b in base["paired_beads"]]
    for r in rows:
        print(json.dumps(r), flush=True)
    again = [run(again_from=f) for f in (50, 100, 150)]
    for r in again:
        print(json.dumps(r), flush=True)
    print(f"as seeded: {base['pairs']} pairs, {len(base['wrong'])} wrong; markers with 3D {base['markers_with_3d']}, "
          f"XYZ {base['xyz_mean_error_mm']:.3f} / {base['xyz_p95_error_mm']:.3f} mm (measured rows "
          f"{base['xyz_measured_mean_error_mm']:.3f} / {base['xyz_measured_p95_error_mm']:.3f} mm)")
    print(f"one paired bead's side marker removed: {sum(bool(r['wrong']) for r in rows)} of {len(rows)} runs "
          f"made a wrong pair, {sum(len(r['wrong']) for r in rows)} wrong of {sum(r['pairs'] for r in rows)} pairs")
    for r in again:
        print(f"tracked again from {r['again_from']}: {r['mean_error_px']:.4f} / {r['p95_error_px']:.4f} px, "
              f"{r['false_locks']} false locks, flagged truly hidden {r['flagged_truly_hidden_pct']:.1f} %, visible "
              f"tracked {r['visible_tracked_pct']:.2f} %, {r['identity_switches']} switches; markers with 3D "
              f"{r['markers_with_3d']}, XYZ {r['xyz_mean_error_mm']:.3f} / {r['xyz_p95_error_mm']:.3f} mm (measured "
              f"rows {r['xyz_measured_mean_error_mm']:.3f} / {r['xyz_measured_p95_error_mm']:.3f} mm)")
