"""World XYZ (mm) of the tracked markers, by triangulation and by the regression model.

`compute_xyz` returns one row per side frame, marker and method with the columns XYZ_COLUMNS:

- ``frame``, ``time_s``: the side camera's frame index and time (s).
- ``status_side``, ``status_front``: the point statuses used ("missing" where a camera has no
  point). The front status is the worse of the two front frames interpolated between.
- ``xs, ys``: side pixels; ``xf, yf``: front pixels at the side frame's time. The cameras are not
  frame-locked: side time t is front time t - offset_s (sync offset: the front started that much
  later), which usually falls between two front frames, so the front pixels are interpolated
  linearly between them, and only when both are real observations (status other than "lost").
- ``X_mm, Y_mm, Z_mm``: world frame; NaN when a camera has no usable point.
- ``method``: "triangulation", "mlp", "residual" (triangulation + learned correction), or
  "mlp_outside": an MLP result whose query lies outside the training volume (pixels beyond the
  training range or XYZ more than a few mm outside the hull of the training points), where the MLP
  extrapolates badly. With ``outside="nan"`` such rows stay "mlp" but get NaN XYZ; with
  ``outside="keep"`` they are left unflagged.
- ``residual_px``: RMS reprojection error of the XYZ through the calibration (px); a large value
  means the two views do not agree (a bad track or a poor model). NaN without a calibration.

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

XYZ_COLUMNS = ["frame", "time_s", "marker", "status_side", "status_front", "xs", "ys", "xf", "yf",
               "X_mm", "Y_mm", "Z_mm", "method", "residual_px"]
METHODS = ("triangulation", "mlp", "residual")
METHOD_CHOICES = ("triangulation", "mlp", "residual", "both", "all")
OUTSIDE_POLICIES = ("flag", "nan", "keep")
# Worse statuses win when two front observations are combined.
_SEVERITY = {"manual": 0, "tracked": 1, "imported": 2, "interpolated": 3, "occluded": 4, "lost": 5,
             "missing": 6}
_EPS = 1e-6
_KEY = 1 << 32  # (marker, frame) -> one int64 key


class Timeline:
    """Frame times of both cameras and the sync offset."""

    def __init__(self, side_fps: float, front_fps: float, offset_s: float, side_frames: int | None = None,
                 front_frames: int | None = None, side_times=None, front_times=None):
        self.side_fps, self.front_fps, self.offset_s = float(side_fps), float(front_fps), float(offset_s)
        self.side_frames, self.front_frames = side_frames, front_frames
        self.side_times = None if side_times is None else np.asarray(side_times, dtype=float)
        self.front_times = None if front_times is None else np.asarray(front_times, dtype=float)
        if self.side_times is not None:
            self.side_frames = len(self.side_times)
        if self.front_times is not None:
            self.front_frames = len(self.front_times)

    @classmethod
    def from_project(cls, project, times: dict | None = None) -> Timeline:
        vids = project.videos()
        times = times or {}
        fps = {c: (vids[c].fps if c in vids and vids[c].fps else 50.0) for c in ("side", "front")}
        count = {c: (vids[c].frames if c in vids else None) for c in ("side", "front")}
        return cls(fps["side"], fps["front"], project.sync_offset_s, count["side"], count["front"],
                   times.get("side"), times.get("front"))

    def side_time(self, i: np.ndarray) -> np.ndarray:
        i = np.asarray(i, dtype=np.int64)
        if self.side_times is not None:
            return self.side_times[np.clip(i, 0, len(self.side_times) - 1)]
        return i / self.side_fps

    def front_index(self, side_index: np.ndarray) -> np.ndarray:
        """Continuous front frame index at each side frame's time (may lie outside the front video)."""
        tf = self.side_time(side_index) - self.offset_s
        if self.front_times is not None:
            ft = self.front_times
            u = np.interp(tf, ft, np.arange(len(ft), dtype=float))
            # beyond either end: continue at the nominal frame rate
            return np.where(tf < ft[0], (tf - ft[0]) * self.front_fps,
                            np.where(tf > ft[-1], len(ft) - 1 + (tf - ft[-1]) * self.front_fps, u))
        return tf * self.front_fps

    def front_position(self, side_index: np.ndarray) -> np.ndarray:
        """front_index, NaN outside the front video (no extrapolation: a side frame before the first or
        after the last front frame has no front point)."""
        u = self.front_index(side_index)
        last = math.inf if self.front_frames is None else self.front_frames - 1
        inside = (u >= -_EPS) & (u <= last + _EPS)
        return np.where(inside, np.clip(u, 0, None), np.nan)

    def side_index_of_front(self, front_index: np.ndarray) -> np.ndarray:
        """Nearest side frame for each front frame."""
        j = np.asarray(front_index, dtype=np.int64)
        tf = self.front_times[np.clip(j, 0, len(self.front_times) - 1)] if self.front_times is not None \
            else j / self.front_fps
        ts = tf + self.offset_s
        if self.side_times is not None:
            return np.clip(np.searchsorted(self.side_times, ts), 0, len(self.side_times) - 1)
        return np.rint(ts * self.side_fps).astype(np.int64)


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


# -- main entry points ----------------------------------------------------------------------------
def compute_xyz(project, method: str = "both", frames=None, model=None, calibration=None,
                times: dict | None = None, outside: str = "flag", refine: bool = True) -> pd.DataFrame:
    """XYZ of every marker at every side frame (or only `frames`: an iterable of side frame
    indices). method: "triangulation", "mlp", "residual", "both" (triangulation + mlp) or "all".
    An explicitly asked method that cannot run (no calibration, no model) raises SandtrackError;
    "both"/"all" give what is available and raise only if nothing is."""
    if method not in METHOD_CHOICES:
        raise SandtrackError(f"unknown method {method!r} (one of {', '.join(METHOD_CHOICES)})")
    if outside not in OUTSIDE_POLICIES:
        raise SandtrackError(f"unknown outside policy {outside!r} (one of {', '.join(OUTSIDE_POLICIES)})")
    timeline = Timeline.from_project(project, times)
    calibration = calibration if calibration is not None else project_calibration(project)
    methods, model = _resolve_methods(project, method, model, calibration)
    obs = _observations(project, timeline, frames)
    return _solve(obs, methods, model, calibration, outside, refine)


def xyz_at_frame(project, frame: int, method: str = "both", **kw) -> pd.DataFrame:
    """The rows of one side frame (fast: reads only that frame's points; the model is cached)."""
    return compute_xyz(project, method=method, frames=[int(frame)], **kw)


def _resolve_methods(project, method: str, model, calibration):
    wanted = {"both": ["triangulation", "mlp"], "all": list(METHODS)}.get(method, [method])
    strict = method in METHODS
    if model is None and ("mlp" in wanted or "residual" in wanted):
        path = model_path(project)
        if path is not None and (strict or path.exists()):
            model = load_cached_model(path)
        elif strict:
            raise SandtrackError("the project has no regression model yet (sandtrack train ... --project P)")
    out = []
    for m in wanted:
        if m == "triangulation" and calibration is None:
            if strict:
                raise SandtrackError("the project has no calibration yet (sandtrack calibrate, or set one in the TUI)")
            continue
        if m in ("mlp", "residual") and model is None:
            continue
        if m == "residual" and not model.has_residual:
            if strict:
                raise SandtrackError("the model has no residual variant (train it with a calibration)")
            continue
        out.append(m)
    if not out:
        raise SandtrackError("nothing to compute XYZ with: the project needs a calibration or a trained model")
    return out, model


def _observations(project, timeline: Timeline, frames) -> dict:
    """One row per (side frame, marker): side pixels and front pixels interpolated to its time."""
    wanted = None
    if frames is not None:
        wanted = np.unique(np.asarray(list(frames), dtype=np.int64))
        if len(wanted) == 0:
            wanted = np.zeros(0, np.int64)
            lo, hi = 0, -1
        else:
            lo, hi = int(wanted[0]), int(wanted[-1])
        side = project.points(camera="side", frames=(lo, hi))
        u = timeline.front_index(np.array([lo, hi]))
        front = project.points(camera="front", frames=(int(np.floor(u[0])) - 1, int(np.ceil(u[1])) + 1))
    else:
        side = project.points(camera="side")
        front = project.points(camera="front")

    keys = [side[["frame", "marker"]].to_numpy(np.int64)]
    if len(front):
        keys.append(np.stack([timeline.side_index_of_front(front["frame"].to_numpy()),
                              front["marker"].to_numpy(np.int64)], axis=1))
    keys = np.unique(np.concatenate(keys), axis=0)
    if wanted is not None:
        keys = keys[np.isin(keys[:, 0], wanted)]
    keys = keys[keys[:, 0] >= 0]
    if timeline.side_frames is not None:
        keys = keys[keys[:, 0] < timeline.side_frames]
    frame, marker = keys[:, 0], keys[:, 1]
    obs = {"frame": frame, "marker": marker, "time_s": timeline.side_time(frame)}
    obs["xs"], obs["ys"], obs["status_side"], ok = _lookup(side, marker, frame)
    lost = obs["status_side"] == "lost"
    obs["xs"][lost] = np.nan
    obs["ys"][lost] = np.nan
    _interpolate_front(obs, front, timeline.front_position(frame))
    return obs


def _lookup(points: pd.DataFrame, marker: np.ndarray, frame: np.ndarray):
    """x, y, status (\"missing\" where absent) and usability of each (marker, frame) in `points`."""
    n = len(marker)
    x, y = np.full(n, np.nan), np.full(n, np.nan)
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
    usable = (status != "lost") & (status != "missing") & np.isfinite(x) & np.isfinite(y)
    return x, y, status, usable


def _interpolate_front(obs: dict, front: pd.DataFrame, u: np.ndarray) -> None:
    """Fill obs xf, yf, status_front from the two front frames around continuous index u."""
    n = len(u)
    j0 = np.floor(np.nan_to_num(u, nan=-10) + _EPS).astype(np.int64)
    w = np.where(np.isfinite(u), u - j0, np.nan)
    w[np.abs(w) < _EPS] = 0.0
    x0, y0, s0, ok0 = _lookup(front, obs["marker"], j0)
    x1, y1, s1, ok1 = _lookup(front, obs["marker"], j0 + 1)
    exact = w == 0.0
    one = exact & ok0
    both = ok0 & ok1 & ~exact & np.isfinite(w)
    xf, yf = np.full(n, np.nan), np.full(n, np.nan)
    xf[one], yf[one] = x0[one], y0[one]
    xf[both] = (1 - w[both]) * x0[both] + w[both] * x1[both]
    yf[both] = (1 - w[both]) * y0[both] + w[both] * y1[both]
    sev0 = np.array([_SEVERITY.get(v, 6) for v in s0], dtype=int)
    sev1 = np.array([_SEVERITY.get(v, 6) for v in s1], dtype=int)
    status = np.where(exact | (sev0 >= sev1), s0, s1).astype(object)
    status[~np.isfinite(u)] = "missing"
    obs["xf"], obs["yf"], obs["status_front"] = xf, yf, status


def _solve(obs: dict, methods: list[str], model, calibration, outside: str, refine: bool) -> pd.DataFrame:
    from .triangulation import triangulate

    pix = np.stack([obs[c] for c in ("xs", "ys", "xf", "yf")], axis=1) if len(obs["frame"]) else np.zeros((0, 4))
    ok = np.isfinite(pix).all(axis=1)
    n = len(pix)
    cols: dict[str, list] = {c: [] for c in XYZ_COLUMNS}
    for m in methods:
        xyz = np.full((n, 3), np.nan)
        res = np.full(n, np.nan)
        label = np.full(n, m, dtype=object)
        if ok.any():
            if m == "triangulation":
                pts, r = triangulate(calibration, {"side": pix[ok, :2], "front": pix[ok, 2:]}, refine=refine,
                                     world=True)
                xyz[ok], res[ok] = pts, r
            else:
                network_rows(m, model, calibration, pix, outside, xyz, res, label)
        for c in ("frame", "time_s", "marker", "status_side", "status_front", "xs", "ys", "xf", "yf"):
            cols[c].append(obs[c])
        for k, c in enumerate(("X_mm", "Y_mm", "Z_mm")):
            cols[c].append(xyz[:, k])
        cols["method"].append(label)
        cols["residual_px"].append(res)
    table = pd.DataFrame({c: np.concatenate(v) if v else np.zeros(0) for c, v in cols.items()})
    order = np.lexsort((np.repeat(np.arange(len(methods)), n), table["marker"].to_numpy(),
                        table["frame"].to_numpy()))
    table = table.iloc[order].reset_index(drop=True)
    table["frame"] = table["frame"].astype(np.int64)
    table["marker"] = table["marker"].astype(np.int64)
    for c in ("status_side", "status_front", "method"):
        table[c] = table[c].astype(object)
    return table


def network_rows(m: str, model, calibration, x: np.ndarray, outside: str, xyz: np.ndarray, res: np.ndarray,
                 label: np.ndarray) -> None:
    """Fill xyz, res and label (in place) for the rows of x (N, 4: xs, ys, xf, yf) without a missing
    pixel, by the network ("mlp") or its residual variant: the reprojection residual through the
    calibration (else the model's own), MLP rows outside the training volume flagged "mlp_outside"
    (outside="flag"), emptied ("nan") or left ("keep")."""
    from .regression import outside_training, predict
    from .triangulation import reprojection_residual

    ok = np.isfinite(x).all(axis=1)
    if not ok.any():
        return
    xyz[ok] = predict(model, x[ok], method=m)
    cal = calibration if calibration is not None else model.calibration
    if cal is not None and {"side", "front"} <= set(cal.cameras):
        res[ok] = reprojection_residual(cal, {"side": x[ok, :2], "front": x[ok, 2:]}, cal.to_rig(xyz[ok]))
    if m == "mlp" and outside != "keep":
        out = np.zeros(len(x), bool)
        out[ok] = outside_training(model, x[ok], xyz[ok])
        if outside == "flag":
            label[out] = "mlp_outside"
        else:
            xyz[out] = np.nan
