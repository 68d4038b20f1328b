"""Angle of repose: from side photos and videos of a heap, and from DEM particle dumps.

`measure_path(path, ...)` picks the method from the file: a photo (`image.measure_image`), a video
(`image.measure_video`: the angle over time and its settled value), a LIGGGHTS/LAMMPS dump or an
exchange CSV (`particles.measure_particles`, per output step), a saved ``--json`` result, or a folder
of any of these (each measured; their mean and spread).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import SandtrackError
from .fit import settled_value
from .image import BAND, ImageResult, SeriesResult, measure_image, measure_video, read_image
from .particles import DumpResult, measure_particles

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
VIDEO_SUFFIXES = {".mp4", ".mov", ".avi", ".mkv", ".m4v", ".mts", ".webm"}


def kind_of(path: str | Path) -> str:
    """"folder", "image", "video", "result" (a saved JSON result), "dump" or "csv"."""
    s = str(path)
    if any(ch in s for ch in "*?["):
        return "dump"
    p = Path(s)
    if p.is_dir():
        return "folder"
    if not p.is_file():
        raise SandtrackError(f"file not found: {p}")
    suffix = p.suffix.lower()
    if suffix in IMAGE_SUFFIXES:
        return "image"
    if suffix in VIDEO_SUFFIXES:
        return "video"
    if suffix == ".json":
        return "result"
    try:
        import gzip

        with (gzip.open(p, "rt", errors="replace") if suffix == ".gz" else open(p, errors="replace")) as fh:
            head = fh.read(400)
    except OSError as exc:
        raise SandtrackError(f"cannot read {p}: {exc}") from None
    if "ITEM:" in head:
        return "dump"
    first = head.splitlines()[0] if head else ""
    if "," in first:
        return "csv"
    raise SandtrackError(f"{p}: not a photo, video, DEM dump or exchange CSV")


@dataclass
class FolderResult:
    source: str
    rows: list[dict]  # file, kind, angle_deg, sigma_deg, error
    results: list = field(default_factory=list)

    @property
    def angles(self) -> np.ndarray:
        return np.array([r["angle_deg"] for r in self.rows if r.get("angle_deg") is not None], float)

    @property
    def angle_deg(self) -> float:
        a = self.angles
        return float(a.mean()) if len(a) else float("nan")

    @property
    def sd_deg(self) -> float:
        a = self.angles
        return float(a.std(ddof=1)) if len(a) > 1 else 0.0

    def to_dict(self) -> dict:
        return {"source": self.source, "kind": "folder", "angle_deg": self.angle_deg, "sd_deg": self.sd_deg,
                "measured": int(len(self.angles)), "files": self.rows}


def result_angle(res) -> tuple[float, float]:
    """(angle, its uncertainty) of any result: the settled value for a series."""
    if isinstance(res, SeriesResult):
        return res.angle, (float("nan") if res.settled is None else res.settled.sd_deg)
    if isinstance(res, FolderResult):
        return res.angle_deg, res.sd_deg
    if isinstance(res, DumpResult):
        return res.angle_deg, res.sem_deg
    if isinstance(res, dict):
        return float(res["angle_deg"]), float(res.get("sigma_deg") or res.get("sem_deg") or res.get("sd_deg") or 0)
    return res.angle_deg, res.sigma_deg


def load_result(path: str | Path) -> dict:
    """A result saved with ``sandtrack repose --json``: its dict (must hold angle_deg)."""
    p = Path(path)
    try:
        d = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SandtrackError(f"{p}: not a readable JSON result ({str(exc)[:80]})") from None
    if not isinstance(d, dict) or not isinstance(d.get("angle_deg"), (int, float)):
        raise SandtrackError(f"{p}: a repose result needs a numeric angle_deg")
    return d


def measure_dem(path, up: str | None = None, units: str | None = None, dt: float | None = None,
                types: list[int] | None = None, slices: int | None = None, band=BAND, progress=None,
                should_stop=None):
    """A DEM file: a DumpResult for one output step, a SeriesResult (kind "dump") for several."""
    from ..dem import read_dem

    kind = kind_of(path)
    kw = {"units": units, "extra": ("type", "radius")}
    if kind == "dump":
        kw["dt"] = dt or 1.0
    df = read_dem(path, "dump" if kind == "dump" else "csv", **kw)
    time_unit = "s" if (kind != "dump" or dt or _dump_has_time(path)) else "step"
    if types:
        if "type" not in df.columns:
            raise SandtrackError(f"{path}: no particle type column to select types {types} from")
        df = df[df["type"].isin(types)]
        if df.empty:
            raise SandtrackError(f"{path}: no particle of type {', '.join(map(str, types))}")
    steps = list(df.groupby("time_s", sort=True))
    results = []
    for k, (t, g) in enumerate(steps):
        if should_stop is not None and should_stop():
            break
        rad = g["radius_mm"].to_numpy() if "radius_mm" in g.columns else None
        results.append(measure_particles(g[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), up, slices, band, rad,
                                         source=str(path), time=float(t)))
        if progress is not None:
            progress(k + 1, len(steps))
    if df.attrs.get("units_guessed"):
        for r in results:
            r.warnings.append(f"length unit not given: positions taken as {df.attrs['units_guessed']} from their "
                              "extent (the angle does not depend on it)")
    if len(results) == 1:
        return results[0]
    t = np.array([r.time for r in results])
    a = np.array([r.angle_deg for r in results])
    nan = np.full(len(t), np.nan)
    return SeriesResult(str(path), "dump", t, a, nan, nan, np.array([r.sem_deg for r in results]),
                        settled_value(t, a), time_unit=time_unit, last=results[-1])


def _dump_has_time(path) -> bool:
    from ..dem import _dump_paths, _open_text

    return "ITEM: TIME\n" in _open_text(_dump_paths(path)[0])[:4000]


def measure_path(path, *, side: str = "both", band=BAND, calibration=None, camera: str | None = None,
                 scale_mm_per_px: float | None = None, every_s: float | None = None, up: str | None = None,
                 units: str | None = None, dt: float | None = None, types: list[int] | None = None,
                 slices: int | None = None, progress=None, should_stop=None, _in_folder: bool = False):
    """Measure any supported input (see module docstring)."""
    kind = kind_of(path)
    image_kw = {"side": side, "band": band, "calibration": calibration, "camera": camera,
                "scale_mm_per_px": scale_mm_per_px}
    if kind == "image":
        return measure_image(read_image(path), source=str(path), **image_kw)
    if kind == "video":
        return measure_video(path, every_s=every_s, progress=progress, should_stop=should_stop, **image_kw)
    if kind in ("dump", "csv"):
        return measure_dem(path, up, units, dt, types, slices, band, progress, should_stop)
    if kind == "result":
        return load_result(path)
    if _in_folder:
        raise SandtrackError(f"{path}: folders inside a folder are not measured")
    files = sorted(p for p in Path(path).iterdir() if p.is_file() and not p.name.startswith("."))
    rows, results = [], []
    for k, f in enumerate(files):
        if should_stop is not None and should_stop():
            break
        try:
            fk = kind_of(f)
        except SandtrackError:
            continue
        try:
            res = measure_path(f, side=side, band=band, calibration=calibration, camera=camera,
                               scale_mm_per_px=scale_mm_per_px, every_s=every_s, up=up, units=units, dt=dt,
                               types=types, slices=slices, _in_folder=True)
            ang, sig = result_angle(res)
            rows.append({"file": f.name, "kind": fk, "angle_deg": ang, "sigma_deg": sig, "error": None})
            results.append(res)
        except SandtrackError as exc:
            rows.append({"file": f.name, "kind": fk, "angle_deg": None, "sigma_deg": None, "error": str(exc)})
        if progress is not None:
            progress(k + 1, len(files))
    if not rows:
        raise SandtrackError(f"{path}: no photo, video, dump or exchange CSV in this folder")
    if not any(r["angle_deg"] is not None for r in rows):
        raise SandtrackError(f"{path}: no file could be measured (first error: {rows[0]['error']})")
    return FolderResult(str(path), rows, results)


__all__ = ["BAND", "DumpResult", "FolderResult", "ImageResult", "SeriesResult", "kind_of", "load_result",
           "measure_dem", "measure_path", "result_angle"]
