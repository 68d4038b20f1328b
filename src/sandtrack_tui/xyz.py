"""World XYZ (mm) of the tracked markers, by triangulation and by the regression model, for a
project with any number of cameras.

`compute_xyz` returns one row per frame of the first camera (the reference: the side camera in a
side/front project), marker and method, with the columns `xyz_columns(cameras)`:

- ``frame``, ``time_s``: the reference camera's frame index and time (s).
- ``status_<camera>`` for each camera: the point status used ("missing" where the camera has no
  point). For the other cameras it is the worse of the two frames interpolated between.
- pixels of each camera at the reference frame's time: ``xs, ys`` (side), ``xf, yf`` (front),
  ``x_<camera>, y_<camera>`` (any other camera). The cameras are not frame-locked: a camera that
  started recording `offset` s later (`video.camera_offsets`: the project's sync offset belongs to
  the front camera, or to the second of two) sees reference time t at its own time t - offset,
  which usually falls between two of its frames; its pixels are interpolated linearly between them,
  and only when both are real observations (status other than "lost").
- ``X_mm, Y_mm, Z_mm``: world frame; NaN when fewer than two calibrated cameras have a usable point.
  Triangulation uses every calibrated camera that has one.
- ``method``: "triangulation", "mlp", "residual" (triangulation + learned correction), or
  "mlp_outside": an MLP result whose query lies outside the training volume (pixels beyond the
  training range or XYZ more than a few mm outside the hull of the training points), where the MLP
  extrapolates badly. With ``outside="nan"`` such rows stay "mlp" but get NaN XYZ; with
  ``outside="keep"`` they are left unflagged. The network reads the side and front pixels, as it
  was trained. A project with one camera has "scale" rows instead: X_mm, Y_mm are the pixel
  (undistorted when the camera is calibrated) times the camera's mm-per-px scale (`scale.py`), in
  the image's axes; Z_mm is NaN. Where no method can give millimetres (one camera without a scale,
  cameras without a calibration or network: `NoXYZ`), `compute_pixels` gives the same table with
  method "pixels" and X_mm, Y_mm, Z_mm NaN: the pixel trajectories alone.
- ``sd_X_mm, sd_Y_mm, sd_Z_mm``: 1-sigma uncertainty of X, Y, Z (mm). For "triangulation" rows each
  pixel's sd (the tracker's estimate where the points table has one, else the camera's calibration RMSE)
  and the calibration's parameter covariance with the world frame's, propagated to first order
  (`triangulation_sd`). For "mlp"
  and "residual" rows the network's spread (`regression.spread`: its error on calibration points it never
  saw, plus the pixels' noise above theirs; a "residual" row's with the calibration's part of the
  triangulation's sd, where the calibration keeps its covariance); NaN outside the training volume and
  for a model file without a spread. NaN where a pixel's sd is not known. With a calibration, an "mlp"
  row's sd is what its spread and the triangulation of the same pixels say together about its error
  (`regression.check`; outside the training volume the triangulation alone).
- ``xyz_source``: "interpolated" (every camera's pixels at the reference time: its own frame or the two
  around it), or "nearest_frame": a camera had a point in only one of the two frames around (a seed
  frame, a track's first or last frame; never next to a "lost" one), so its pixels are that frame's and
  their sd grows by the marker's motion over the time between (its speed from that frame and the next one
  beyond; NaN when the track has no such frame yet).
- ``calibrated_region``: "outside" where a camera's pixel lies beyond the image region its calibration
  points covered (`calibration.region`: there the lens model extrapolates, and the sd leaves out its
  error), "inside" where every calibrated camera's pixel lies within it, "" where the calibration keeps
  no region (imported, or written before regions were kept).
- ``network_check``: for "mlp" rows, "ok" (the network agrees with the triangulation within their
  uncertainties), "inconsistent" (it does not, at the 99 % level; its sd then comes from the disagreement:
  `regression.check`) or "unchecked" (no triangulation: the spread alone; or no spread: the
  disagreement alone); empty for the other methods.
- ``bias_X_mm, bias_Y_mm, bias_Z_mm``: for checked "mlp" rows, the network's error as the triangulation of
  the same pixels measures it (the mean of `regression.check`'s Gaussian; X_mm - bias_X_mm is the best
  estimate of X, and ±1.96 sd_X_mm around X_mm holds the error with 95 % probability); empty elsewhere.
- ``residual_px``: RMS reprojection error of the XYZ through the calibration (px); a large value
  means the views do not agree (a bad track or a poor model). NaN without a calibration.

Frame times come from the project's stored fps (times = index / fps) unless `times` gives each
camera's real frame times (e.g. ``FrameSource.times_s``).
"""

from __future__ import annotations

import math
import threading
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import SandtrackError

METHODS = ("triangulation", "mlp", "residual")
METHOD_CHOICES = ("triangulation", "mlp", "residual", "both", "all")
OUTSIDE_POLICIES = ("flag", "nan", "keep")
NETWORK_CAMERAS = ("side", "front")  # the network's inputs: xs, ys, xf, yf
SD_COLUMNS = ("sd_X_mm", "sd_Y_mm", "sd_Z_mm")
BIAS_COLUMNS = ("bias_X_mm", "bias_Y_mm", "bias_Z_mm")
COV_COLUMNS = ("cov_XY_mm2", "cov_XZ_mm2", "cov_YZ_mm2")  # with covariance=True: the triangulation's, mm²
PARALLEL_ROWS = 100_000  # rows per thread at least: on fewer, the split costs more than the second core saves
_PIXEL_ALIASES = {"side": ("xs", "ys"), "front": ("xf", "yf")}
# Worse statuses win when two observations of a camera are combined.
_SEVERITY = {"manual": 0, "tracked": 1, "imported": 2, "interpolated": 3, "occluded": 4, "lost": 5,
             "missing": 6}
_EPS = 1e-6
_KEY = 1 << 32  # (marker, frame) -> one int64 key


class NoXYZ(SandtrackError):
    """No method can turn these cameras' pixels into millimetres (no scale, calibration or network)."""


def pixel_columns(camera: str) -> tuple[str, str]:
    """The x and y columns of a camera's pixels: xs, ys (side), xf, yf (front), else x_NAME, y_NAME."""
    return _PIXEL_ALIASES.get(camera, (f"x_{camera}", f"y_{camera}"))


def xyz_columns(cameras, covariance: bool = False) -> list[str]:
    """Columns of the XYZ table of a project with these cameras (the first is the reference); with
    `covariance`, the covariances between the axes after the sd."""
    return ["frame", "time_s", "marker", *(f"status_{c}" for c in cameras),
            *(col for c in cameras for col in pixel_columns(c)), "X_mm", "Y_mm", "Z_mm", *SD_COLUMNS,
            *(COV_COLUMNS if covariance else ()), "method", "residual_px", "xyz_source", "calibrated_region",
            "network_check", *BIAS_COLUMNS]


XYZ_COLUMNS = xyz_columns(NETWORK_CAMERAS)
XYZ_SOURCES = ("interpolated", "nearest_frame")


class Timeline:
    """Frame times of the cameras and their start offsets; the first camera is the reference.

    fps, frames, times: per camera (frames / times may be missing: then index / fps, unbounded);
    offsets: how much later (s) each camera started than the reference."""

    def __init__(self, cameras, fps: dict, offsets: dict, frames: dict | None = None, times: dict | None = None):
        self.cameras = list(cameras)
        self.fps = {c: float(fps[c]) for c in self.cameras}
        self.offsets = {c: float(offsets.get(c, 0.0)) for c in self.cameras}
        self.times = {c: np.asarray(t, dtype=float) for c, t in (times or {}).items() if t is not None}
        self.frames = {c: (len(self.times[c]) if c in self.times else (frames or {}).get(c)) for c in self.cameras}

    @classmethod
    def from_project(cls, project, times: dict | None = None) -> Timeline:
        from .video import camera_offsets

        vids = project.videos()
        cameras = [c for c in project.cameras() if c in vids]
        fps = {c: vids[c].fps or 50.0 for c in cameras}
        return cls(cameras, fps, camera_offsets(cameras, project.sync_offset_s),
                   {c: vids[c].frames for c in cameras}, times)

    @property
    def reference(self) -> str:
        return self.cameras[0]

    def time(self, camera: str, index: np.ndarray) -> np.ndarray:
        """Time (s, on the camera's own clock) of its frames."""
        i = np.asarray(index, dtype=np.int64)
        t = self.times.get(camera)
        return t[np.clip(i, 0, len(t) - 1)] if t is not None else i / self.fps[camera]

    def index(self, camera: str, ref_index: np.ndarray) -> np.ndarray:
        """Continuous frame index of `camera` at each reference frame's time (may lie outside its video)."""
        tc = self.time(self.reference, ref_index) - self.offsets[camera]
        ft = self.times.get(camera)
        if ft is not None:
            u = np.interp(tc, ft, np.arange(len(ft), dtype=float))
            # beyond either end: continue at the nominal frame rate
            fps = self.fps[camera]
            return np.where(tc < ft[0], (tc - ft[0]) * fps, np.where(tc > ft[-1], len(ft) - 1 + (tc - ft[-1]) * fps, u))
        return tc * self.fps[camera]

    def position(self, camera: str, ref_index: np.ndarray) -> np.ndarray:
        """`index`, NaN outside the camera's video (no extrapolation: a reference frame before its first
        or after its last frame has no point of that camera)."""
        u = self.index(camera, ref_index)
        n = self.frames.get(camera)
        last = math.inf if n is None else n - 1
        inside = (u >= -_EPS) & (u <= last + _EPS)
        return np.where(inside, np.clip(u, 0, None), np.nan)

    def reference_index(self, camera: str, index: np.ndarray) -> np.ndarray:
        """Nearest reference frame for each frame of `camera`."""
        ts = self.time(camera, index) + self.offsets[camera]
        ref = self.times.get(self.reference)
        if ref is not None:
            return np.clip(np.searchsorted(ref, ts), 0, len(ref) - 1)
        return np.rint(ts * self.fps[self.reference]).astype(np.int64)


# -- model and calibration caches (the live table calls xyz_at_frame on every step) ---------------
_model_lock = threading.Lock()
_model_cache: dict[str, tuple[tuple, object]] = {}


def model_path(project) -> Path | None:
    info = project.get("model")
    if not info or not info.get("path"):
        return None
    p = Path(info["path"])
    return p if p.is_absolute() else (Path(project.path).resolve().parent / p)


def load_cached_model(path: str | Path):
    """The model at `path`, loaded once and reloaded only when the file changes."""
    from .regression import load_model

    p = Path(path).resolve()
    try:
        st = p.stat()
    except OSError:
        raise SandtrackError(f"model file not found: {p} (train again: sandtrack train)") from None
    key = (st.st_mtime_ns, st.st_size)
    with _model_lock:
        hit = _model_cache.get(str(p))
        if hit and hit[0] == key:
            return hit[1]
        model = load_model(p)
        _model_cache[str(p)] = (key, model)
        return model


@lru_cache(maxsize=4)
def _calibration_from_text(text: str):
    from .camera import Calibration

    return Calibration.from_toml(text, source="project calibration")


def project_calibration(project):
    text = project.get("calibration")
    return _calibration_from_text(text) if text else None


def project_sd_holds(project, table: pd.DataFrame) -> str | None:
    """What the sd of a project table's triangulated rows holds, in one line, and a second where some of them
    lie outside the calibrated image region (None without such rows)."""
    from .calibration.region import outside_note
    from .triangulation_sd import sd_holds

    calibration = project_calibration(project)
    if calibration is None or not (table["method"] == "triangulation").any():
        return None
    holds = sd_holds(calibration, project.cameras(), "each tracked point's sd (its match score)")
    note = outside_note(table[table["method"] == "triangulation"])
    return holds if note is None else f"{holds}\n{note}"


# -- main entry points ----------------------------------------------------------------------------
def compute_xyz(project, method: str = "both", frames=None, model=None, calibration=None,
                times: dict | None = None, outside: str = "flag", refine: bool = True,
                covariance: bool = False) -> pd.DataFrame:
    """XYZ of every marker at every reference frame (or only `frames`: an iterable of reference frame
    indices). method: "triangulation", "mlp", "residual", "both" (triangulation + mlp) or "all".
    covariance: also the triangulated rows' covariances between the axes (COV_COLUMNS; NaN elsewhere).
    An explicitly asked method that cannot run (no calibration, no model, too few cameras) raises
    SandtrackError; "both"/"all" give what is available and raise only if nothing is."""
    check_choices(method, outside)
    timeline = Timeline.from_project(project, times)
    if not timeline.cameras:
        raise SandtrackError("the project has no videos")
    calibration = calibration if calibration is not None else project_calibration(project)
    obs = _observations(project, timeline, frames)
    if len(timeline.cameras) == 1:
        return _solve_scaled(project, obs, timeline.reference, calibration)
    if model is None and wants_network(method):
        path = model_path(project)
        if path is not None and (method in METHODS or path.exists()):
            model = load_cached_model(path)
    methods = resolve_methods(method, calibration, model, timeline.cameras, PROJECT_NEEDS)
    return _solve(obs, timeline.cameras, methods, model, calibration, outside, refine, covariance)


def compute_pixels(project, frames=None, times: dict | None = None) -> pd.DataFrame:
    """The table of `compute_xyz` with the pixels only: method "pixels", X_mm, Y_mm, Z_mm and residual_px NaN."""
    timeline = Timeline.from_project(project, times)
    if not timeline.cameras:
        raise SandtrackError("the project has no videos")
    obs = _observations(project, timeline, frames)
    n = len(obs["frame"])
    return _table(obs, timeline.cameras, [_unmeasured_block(n, "pixels")])


def xyz_at_frame(project, frame: int, method: str = "both", **kw) -> pd.DataFrame:
    """The rows of one reference frame (fast: reads only that frame's points; the model is cached)."""
    return compute_xyz(project, method=method, frames=[int(frame)], **kw)


# -- which methods can run --------------------------------------------------------------------------
PROJECT_NEEDS = {
    "calibration": "the project has no calibration yet (sandtrack calibrate, or set one in the TUI)",
    "model": "the project has no regression model yet (sandtrack train ... --project P)",
    "nothing": "nothing to compute XYZ with: the project needs a calibration or a trained model",
}


def check_choices(method: str, outside: str) -> None:
    if method not in METHOD_CHOICES:
        raise SandtrackError(f"unknown method {method!r} (one of {', '.join(METHOD_CHOICES)})")
    if outside not in OUTSIDE_POLICIES:
        raise SandtrackError(f"unknown outside policy {outside!r} (one of {', '.join(OUTSIDE_POLICIES)})")


def wanted_methods(method: str) -> list[str]:
    return {"both": ["triangulation", "mlp"], "all": list(METHODS)}.get(method, [method])


def wants_network(method: str) -> bool:
    return any(m in ("mlp", "residual") for m in wanted_methods(method))


def resolve_methods(method: str, calibration, model, cameras, needs: dict[str, str]) -> list[str]:
    """The methods of `method` that can run with this calibration, model and cameras. A method asked
    for by name that cannot run raises SandtrackError with the reason (`needs` words the missing
    calibration, model and "nothing" for the caller: a project, or the command line's options);
    "both" and "all" keep what can run and raise NoXYZ only when nothing can."""
    strict = method in METHODS
    out, reasons = [], []
    for m in wanted_methods(method):
        reason = _cannot_run(m, calibration, model, list(cameras), needs)
        if reason is None:
            out.append(m)
        elif strict:
            raise SandtrackError(reason)
        elif reason not in (needs["calibration"], needs["model"].format(method=m)):
            reasons.append(reason)  # an input was given but does not fit
    if not out:
        raise NoXYZ("; ".join(reasons) if reasons else needs["nothing"])
    return out


def _cannot_run(m: str, calibration, model, cameras: list[str], needs: dict[str, str]) -> str | None:
    if m == "triangulation":
        if calibration is None:
            return needs["calibration"]
        if sum(c in calibration.cameras for c in cameras) < 2:
            return "triangulation needs the pixels of at least two calibrated cameras"
        return None
    if model is None:
        return needs["model"].format(method=m)
    if not set(NETWORK_CAMERAS) <= set(cameras):
        return (f"the {m} method reads side and front pixels: give xs, ys, xf, yf "
                "(or x_side, y_side, x_front, y_front)")
    if m == "residual" and not model.has_residual:
        return "the model has no residual variant (train it with a calibration)"
    return None


# -- observations -----------------------------------------------------------------------------------
def _observations(project, timeline: Timeline, frames) -> dict:
    """One row per (reference frame, marker): each camera's pixels and status at that frame's time
    (the reference camera's own point; the others' interpolated)."""
    ref = timeline.reference
    others = timeline.cameras[1:]
    wanted = None
    if frames is not None:
        wanted = np.unique(np.asarray(list(frames), dtype=np.int64))
        lo, hi = (int(wanted[0]), int(wanted[-1])) if len(wanted) else (0, -1)
        points = {ref: project.points(camera=ref, frames=(lo, hi))}
        for c in others:
            u = timeline.index(c, np.array([lo, hi]))
            points[c] = project.points(camera=c, frames=(int(np.floor(u[0])) - 1, int(np.ceil(u[1])) + 1))
    else:
        points = {c: project.points(camera=c) for c in timeline.cameras}

    keys = [points[ref][["frame", "marker"]].to_numpy(np.int64)]
    for c in others:
        if len(points[c]):
            keys.append(np.stack([timeline.reference_index(c, points[c]["frame"].to_numpy()),
                                  points[c]["marker"].to_numpy(np.int64)], axis=1))
    keys = np.unique(np.concatenate(keys), axis=0)
    if wanted is not None:
        keys = keys[np.isin(keys[:, 0], wanted)]
    keys = keys[keys[:, 0] >= 0]
    if timeline.frames.get(ref) is not None:
        keys = keys[keys[:, 0] < timeline.frames[ref]]
    frame, marker = keys[:, 0], keys[:, 1]
    obs = {"frame": frame, "marker": marker, "time_s": timeline.time(ref, frame), "pixels": {}, "status": {},
           "sd": {}, "extra": {}, "nearest": np.zeros(len(frame), bool)}
    x, y, status, _, sd = _lookup(points[ref], marker, frame)
    lost = status == "lost"
    x[lost], y[lost] = np.nan, np.nan
    obs["pixels"][ref], obs["status"][ref], obs["sd"][ref] = np.stack([x, y], axis=1), status, sd
    obs["extra"][ref] = np.zeros(len(frame))
    for c in others:
        got = _interpolated(points[c], marker, timeline.position(c, frame))
        obs["pixels"][c], obs["status"][c], obs["sd"][c], obs["extra"][c] = (got["pixels"], got["status"], got["sd"],
                                                                             got["extra"])
        obs["nearest"] |= got["nearest"]
    return obs


def _lookup(points: pd.DataFrame, marker: np.ndarray, frame: np.ndarray):
    """x, y, status (\"missing\" where absent), usability and the tracker's pixel sd (NaN: not known) of
    each (marker, frame) in `points`."""
    n = len(marker)
    x, y, sd = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    status = np.full(n, "missing", dtype=object)
    if len(points) and n:
        pk = points["marker"].to_numpy(np.int64) * _KEY + points["frame"].to_numpy(np.int64)
        order = np.argsort(pk, kind="stable")
        pk = pk[order]
        q = marker.astype(np.int64) * _KEY + frame.astype(np.int64)
        pos = np.clip(np.searchsorted(pk, q), 0, len(pk) - 1)
        hit = pk[pos] == q
        src = order[pos[hit]]
        x[hit] = points["x_px"].to_numpy(float)[src]
        y[hit] = points["y_px"].to_numpy(float)[src]
        status[hit] = points["status"].to_numpy(object)[src]
        if "sd_px" in points.columns:
            sd[hit] = points["sd_px"].to_numpy(float, na_value=np.nan)[src]
        elif "score" in points.columns:
            from .tracking.pixel_sd import point_sd_px

            sd[hit] = point_sd_px(points["score"].to_numpy(float, na_value=np.nan)[src], status[hit])
    usable = (status != "lost") & (status != "missing") & np.isfinite(x) & np.isfinite(y)
    return x, y, status, usable, sd


def _interpolated(points: pd.DataFrame, marker: np.ndarray, u: np.ndarray) -> dict:
    """A camera's pixels (N, 2), statuses, pixel sd (NaN: not known), extra sd from a nearest frame (px;
    NaN where the motion is not known) and which rows took a nearest frame, at continuous frame indices u:
    from the two frames around; where only one of them has a point (a seed frame, the start or end of a
    track; not next to a "lost" one), from that one, its sd enlarged by the marker's motion over the time
    between (the speed from that frame and the one beyond it)."""
    n = len(u)
    j0 = np.floor(np.nan_to_num(u, nan=-10) + _EPS).astype(np.int64)
    w = np.where(np.isfinite(u), u - j0, np.nan)
    w[np.abs(w) < _EPS] = 0.0
    x0, y0, s0, ok0, sd0 = _lookup(points, marker, j0)
    x1, y1, s1, ok1, sd1 = _lookup(points, marker, j0 + 1)
    exact = w == 0.0
    one = exact & ok0
    both = ok0 & ok1 & ~exact & np.isfinite(w)
    x, y, sd = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    x[one], y[one], sd[one] = x0[one], y0[one], sd0[one]
    x[both] = (1 - w[both]) * x0[both] + w[both] * x1[both]
    y[both] = (1 - w[both]) * y0[both] + w[both] * y1[both]
    sd[both] = (1 - w[both]) * sd0[both] + w[both] * sd1[both]
    sev0 = np.array([_SEVERITY.get(v, 6) for v in s0], dtype=int)
    sev1 = np.array([_SEVERITY.get(v, 6) for v in s1], dtype=int)
    status = np.where(exact | (sev0 >= sev1), s0, s1).astype(object)
    extra = np.zeros(n)
    near0 = ok0 & (s1 == "missing") & ~exact & np.isfinite(w)  # a "lost" neighbour still spoils the row
    near1 = ok1 & (s0 == "missing") & ~exact & np.isfinite(w)
    for near, j, step, dist, xs, ys, ss, st in ((near0, j0, -1, w, x0, y0, sd0, s0),
                                                  (near1, j0 + 1, 1, 1 - w, x1, y1, sd1, s1)):
        if not near.any():
            continue
        x[near], y[near], sd[near], status[near] = xs[near], ys[near], ss[near], st[near]
        xb, yb, _, okb, _ = _lookup(points, marker[near], j[near] + step)
        speed = np.where(okb, np.hypot(xs[near] - xb, ys[near] - yb), np.nan)  # px per frame
        extra[near] = speed * dist[near]
    status[~np.isfinite(u)] = "missing"
    return {"pixels": np.stack([x, y], axis=1), "status": status, "sd": sd, "extra": extra,
            "nearest": near0 | near1}


# -- XYZ --------------------------------------------------------------------------------------------
def _solve(obs: dict, cameras: list[str], methods: list[str], model, calibration, outside: str,
           refine: bool, covariance: bool = False) -> pd.DataFrame:
    from .calibration.region import region_labels
    from .triangulation_sd import pixel_sd_axes

    n = len(obs["frame"])
    pix = obs["pixels"]
    tri_cams = [c for c in cameras if calibration is not None and c in calibration.cameras]
    seen = np.sum([np.isfinite(pix[c]).all(axis=1) for c in tri_cams], axis=0) if tri_cams else np.zeros(n)
    ok = seen >= 2
    psd = {c: pixel_sd(obs["sd"][c], obs["extra"][c], calibration, c) for c in cameras}
    tsd = {c: pixel_sd_axes(obs["sd"][c], obs["extra"][c], calibration, c) for c in tri_cams}
    blocks, tri = [], None
    for m in methods:
        xyz, sd, cov = np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.full((n, 3), np.nan)
        res = np.full(n, np.nan)
        label = np.full(n, m, dtype=object)
        check, bias = np.full(n, "", dtype=object), np.full((n, 3), np.nan)
        if m == "triangulation":
            if ok.any():
                used = {c: pix[c][ok] for c in tri_cams}
                xyz[ok], res[ok], both = triangulate_with_sd(calibration, used, {c: tsd[c][ok] for c in tri_cams},
                                                             refine, covariance=True)
                sd[ok], cov[ok] = both[:, :3], both[:, 3:]
            tri = (xyz, sd)
        elif n:
            network_rows(m, model, calibration, np.hstack([pix[c] for c in NETWORK_CAMERAS]), outside, xyz, res,
                         label, sd, np.repeat(np.stack([psd[c] for c in NETWORK_CAMERAS], axis=1), 2, axis=1))
            unknown = ~np.isfinite(np.stack([obs["extra"][c] for c in NETWORK_CAMERAS], axis=1)).all(axis=1)
            sd[unknown] = np.nan  # a nearest frame whose motion is not known
            if m == "mlp":
                check, bias = check_network_rows(calibration, {c: pix[c] for c in tri_cams}, tsd, refine, xyz, sd,
                                                 tri)
        blocks.append((xyz, res, label, sd, check, bias, cov))
    return _table({**obs, "region": region_labels(calibration, pix, n)}, cameras, blocks, covariance)


def pixel_sd(sd: np.ndarray, extra: np.ndarray, calibration, camera: str) -> np.ndarray:
    """Each pixel's sd (px): its own (the tracker's, `tracking.pixel_sd`, or the table's), else (NaN) the
    camera's calibration RMSE per axis (NaN without either), combined with `extra` (motion to a nearest
    frame; NaN: unknown). inf (a predicted point) stays inf: its XYZ gets no sd."""
    cam = calibration.cameras.get(camera) if calibration is not None else None
    base = np.where(np.isnan(sd), axis_sd(cam), sd)
    return np.hypot(base, extra)


def check_network_rows(calibration, pixels: dict, pixel_sd: dict, refine: bool, xyz: np.ndarray, sd: np.ndarray,
                       done: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The MLP's rows checked against triangulation (`regression.check`): their sd (N, 3) set in place
    from the spread and the disagreement; the verdict per row ("ok", "inconsistent"; "unchecked" for an
    XYZ without a check: no triangulation, or no spread, whose sd then comes from the disagreement alone;
    "" without an XYZ) and the network's estimated error (N, 3) mm (NaN where not measured). `pixels`,
    `pixel_sd`: the calibrated cameras' (N, 2) px and sd ((N,) or (N, 2) per image axis); `done`: the
    triangulation's XYZ and sd of these rows when already computed."""
    from .regression.check import UNCHECKED, check_network
    from .triangulation_sd import triangulation_sd

    verdict = np.full(len(xyz), "", dtype=object)
    verdict[np.isfinite(xyz).all(axis=1)] = UNCHECKED
    bias = np.full((len(xyz), 3), np.nan)
    seen = np.sum([np.isfinite(p).all(axis=1) for p in pixels.values()], axis=0) if pixels else 0
    rows = np.isfinite(xyz).all(axis=1) & (seen >= 2)
    if not rows.any():
        return verdict, bias
    used = {c: p[rows] for c, p in pixels.items()}
    used_sd = {c: v[rows] for c, v in pixel_sd.items()}
    if done is None:
        tri, _, tri_sd = triangulate_with_sd(calibration, used, used_sd, refine)
    else:
        tri, tri_sd = done[0][rows], done[1][rows]
    tri_sd_pixels = triangulation_sd(calibration, used, calibration.to_rig(tri), used_sd, with_calibration=False)
    sd[rows], verdict[rows], bias[rows] = check_network(xyz[rows], sd[rows], tri, tri_sd, tri_sd_pixels)
    return verdict, bias


def triangulate_with_sd(calibration, pixels: dict, sd: dict, refine: bool, covariance: bool = False):
    """XYZ (world, mm), residual (px) and sd per world axis (mm) of `triangulation.triangulate`, the sd by
    `triangulation_sd` (pixel noise and the calibration's parameter covariance; with `covariance`, (N, 6):
    the sd and the covariances XY, XZ, YZ in mm²). Many rows are split in contiguous parts, one per core,
    computed on threads at once (the kernels and numpy release the GIL)."""
    from .cores import usable_cores

    n = len(next(iter(pixels.values()))) if pixels else 0
    threads = min(usable_cores(), n // PARALLEL_ROWS)
    if threads < 2:
        return _triangulate_with_sd(calibration, pixels, sd, refine, covariance)
    edges = np.linspace(0, n, threads + 1).astype(int)

    def part(k: int):
        rows = slice(edges[k], edges[k + 1])
        return _triangulate_with_sd(calibration, {c: p[rows] for c, p in pixels.items()},
                                    {c: v[rows] if np.ndim(v) and len(v) == n else v for c, v in sd.items()}, refine,
                                    covariance)

    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(threads) as pool:
        done = list(pool.map(part, range(threads)))
    return tuple(np.concatenate([d[k] for d in done]) for k in range(3))


def _triangulate_with_sd(calibration, pixels: dict, sd: dict, refine: bool, covariance: bool = False):
    from .triangulation import triangulate
    from .triangulation_sd import triangulation_sd

    xyz, res = triangulate(calibration, pixels, refine=refine, world=False)
    return calibration.to_world(xyz), res, triangulation_sd(calibration, pixels, xyz, sd, covariance=covariance)


def _solve_scaled(project, obs: dict, camera: str, calibration) -> pd.DataFrame:
    """One camera: the pixels in mm through the camera's scale (method "scale"; no Z)."""
    from .calibration.region import region_labels
    from .scale import project_scale, to_mm

    found = project_scale(project, camera, calibration)
    if found is None:
        raise NoXYZ(f"one camera ({camera}) without a scale: set one (a known length in the TUI, or a "
                    "calibration of the camera), then its pixels give x, y in mm")
    cam = calibration.cameras.get(camera) if calibration is not None else None
    n = len(obs["frame"])
    block = _unmeasured_block(n, "scale")
    block[0][:, :2] = to_mm(obs["pixels"][camera], found[0], cam)
    return _table({**obs, "region": region_labels(calibration, obs["pixels"], n)}, [camera], [block])


def _unmeasured_block(n: int, method: str) -> tuple:
    """A `_table` block of n rows of `method` with every figure NaN (xyz, res, label, sd, check, bias, cov)."""
    return (np.full((n, 3), np.nan), np.full(n, np.nan), np.full(n, method, dtype=object), np.full((n, 3), np.nan),
            np.full(n, "", dtype=object), np.full((n, 3), np.nan), np.full((n, 3), np.nan))


def _table(obs: dict, cameras: list[str], blocks: list, covariance: bool = False) -> pd.DataFrame:
    """The rows of every method's block (xyz, res, label, sd, check, bias, cov), ordered by frame, marker
    and method; with `covariance`, each block's cov in COV_COLUMNS."""
    n = len(obs["frame"])
    columns = xyz_columns(cameras, covariance)
    cols: dict[str, list] = {c: [] for c in columns}
    for xyz, res, label, sd, check, bias, cov in blocks:
        if covariance:
            for k, c in enumerate(COV_COLUMNS):
                cols[c].append(cov[:, k])
        for c in ("frame", "time_s", "marker"):
            cols[c].append(obs[c])
        for c in cameras:
            cols[f"status_{c}"].append(obs["status"][c])
            xc, yc = pixel_columns(c)
            cols[xc].append(obs["pixels"][c][:, 0])
            cols[yc].append(obs["pixels"][c][:, 1])
        for k, c in enumerate(("X_mm", "Y_mm", "Z_mm")):
            cols[c].append(xyz[:, k])
        for k, c in enumerate(SD_COLUMNS):
            cols[c].append(sd[:, k])
        cols["method"].append(label)
        cols["residual_px"].append(res)
        cols["xyz_source"].append(np.where(obs.get("nearest", np.zeros(n, bool)), XYZ_SOURCES[1],
                                           XYZ_SOURCES[0]).astype(object))
        cols["calibrated_region"].append(obs.get("region", np.full(n, "", dtype=object)))
        cols["network_check"].append(check)
        for k, c in enumerate(BIAS_COLUMNS):
            cols[c].append(bias[:, k])
    table = pd.DataFrame({c: np.concatenate(v) if v else np.zeros(0) for c, v in cols.items()})
    order = np.lexsort((np.repeat(np.arange(len(blocks)), n), table["marker"].to_numpy(),
                        table["frame"].to_numpy()))
    table = table.iloc[order].reset_index(drop=True)
    table["frame"] = table["frame"].astype(np.int64)
    table["marker"] = table["marker"].astype(np.int64)
    for c in [*(f"status_{c}" for c in cameras), "method", "xyz_source", "calibrated_region", "network_check"]:
        table[c] = table[c].astype(object)
    return table


def network_rows(m: str, model, calibration, x: np.ndarray, outside: str, xyz: np.ndarray, res: np.ndarray,
                 label: np.ndarray, sd: np.ndarray, pixel_sd: np.ndarray | None = None) -> None:
    """Fill xyz, res, label and sd (in place) for the rows of x (N, 4: xs, ys, xf, yf) without a
    missing pixel, by the network ("mlp") or its residual variant: the reprojection residual through the
    calibration (else the model's own), the sd of `regression.predict_with_sd` (each pixel's sd:
    `pixel_sd` (N, 4) px where finite, else the camera's calibration RMSE), MLP rows outside the training
    volume flagged "mlp_outside" (outside="flag"), emptied ("nan") or left ("keep"; their sd stays NaN)."""
    from .regression import outside_training, predict_with_sd
    from .triangulation import reprojection_residual

    ok = np.isfinite(x).all(axis=1)
    if not ok.any():
        return
    cal = calibration if calibration is not None else model.calibration
    psd = _camera_pixel_sd(cal)
    if pixel_sd is not None:
        given = np.asarray(pixel_sd, float)[ok]
        psd = np.where(np.isfinite(given), given, np.nan if psd is None else psd)
    xyz[ok], sd[ok] = predict_with_sd(model, x[ok], method=m, pixel_sd=psd)
    if cal is not None and {"side", "front"} <= set(cal.cameras):
        res[ok] = reprojection_residual(cal, {"side": x[ok, :2], "front": x[ok, 2:]}, cal.to_rig(xyz[ok]))
        if m == "residual" and (cal.uncertainty or cal.rig_uncertainty is not None):
            # the correction learnt the calibration points' places, which carry the calibration's own error
            # (the world frame's above all) as the triangulation does: its spread, measured against those
            # places, cannot show it
            sd[ok] = np.hypot(sd[ok], calibration_part_sd(cal, x[ok], cal.to_rig(xyz[ok])))
    if m == "mlp" and outside != "keep":
        out = np.zeros(len(x), bool)
        out[ok] = outside_training(model, x[ok], xyz[ok])
        if outside == "flag":
            label[out] = "mlp_outside"
        else:
            xyz[out] = np.nan


def calibration_part_sd(calibration, x: np.ndarray, points_rig: np.ndarray) -> np.ndarray:
    """(N, 3) mm: the calibration's part of the triangulation sd of pixels x (N, 4: xs, ys, xf, yf) at
    `points_rig` (the pixels' own noise left out)."""
    from .triangulation_sd import triangulation_sd

    pixels = {"side": x[:, :2], "front": x[:, 2:]}
    return triangulation_sd(calibration, pixels, points_rig, {c: 0.0 for c in pixels})


def _camera_pixel_sd(calibration) -> np.ndarray | None:
    """(4,) px for xs, ys, xf, yf: the side and front cameras' calibration RMSE, None if not known."""
    cams = calibration.cameras if calibration is not None else {}
    sd = [axis_sd(cams.get(c)) for c in NETWORK_CAMERAS]
    if not np.isfinite(sd).all():
        return None
    return np.repeat(np.asarray(sd, float), 2)


def axis_sd(camera) -> float:
    """A camera's pixel noise per image axis (px): its calibration RMSE, a 2-D distance, over √2; NaN
    when not known."""
    return camera.rmse_axis_px if camera is not None else math.nan
