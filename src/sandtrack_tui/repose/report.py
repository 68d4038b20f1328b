"""Angle-of-repose results as terminal text (tables and a braille plot) and as a PNG figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..compare import text_plot
from ..errors import SandtrackError
from . import FolderResult
from .image import ImageResult, SeriesResult
from .particles import DumpResult


def _f(v, fmt=".2f", none="-") -> str:
    return none if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)


def image_text(r: ImageResult, width: int = 60, plot: bool = True) -> str:
    lines = [f"{r.source}: angle of repose {r.angle_deg:.2f} deg ± {r.sigma_deg:.2f} "
             f"({'mean of both flanks' if len(r.flanks) == 2 else 'one flank'}; {r.geometry})",
             "  flank   angle   ±1σ   lower half  upper half  band       points  inliers  rms px"]
    for f in r.flanks.values():
        lines.append(f"  {f.side:<6} {f.angle_deg:6.2f}  {f.sigma_deg:5.2f}  {_f(f.lower_deg):>10}  "
                     f"{_f(f.upper_deg):>10}  {f.band[0]:.2f}-{f.band[1]:.2f}  {f.points:6d}  {f.inliers:7d}  "
                     f"{f.rms_px:6.2f}")
    size = f"heap {r.height_px:.0f} px high"
    if r.height_mm is not None:
        size += f" ({r.height_mm:.1f} mm)"
    if r.base_width_px is not None:
        size += f", toe to toe {r.base_width_px:.0f} px"
        if r.base_width_mm is not None:
            size += f" ({r.base_width_mm:.1f} mm)"
    if r.base_tilt_deg is not None:
        size += f", toes {r.base_tilt_deg:+.2f} deg off level"
    lines.append("  " + size)
    lines += [f"  ! {w}" for w in r.warnings]
    if plot and r.outline is not None:
        o = r.outline
        series = [("outline", o.x, -o.y)]
        for f in r.flanks.values():
            xs = np.linspace(*f.x_range_px, 20)
            series.append((f"{f.side} fit", xs, -(f.intercept_px + f.slope * xs)))
        lines.append(text_plot(series, width, 10, y_label="-row (px)", x_label="column (px)"))
    return "\n".join(lines)


def dump_text(r: DumpResult, width: int = 60, plot: bool = True) -> str:
    when = "" if r.time is None else f" at {r.time:g}"
    lines = [f"{r.source}{when}: angle of repose {r.angle_deg:.2f} deg (mean of {len(r.slices)} radial slices; "
             f"SD {r.sd_deg:.2f}, standard error {r.sem_deg:.2f}); one cone fitted: {r.cone_angle_deg:.2f} deg",
             f"  up {r.up_axis}; {r.particles} particles, {r.surface_particles} on the surface, diameter "
             f"{r.diameter_mm:.2f} mm; heap {r.height_mm:.1f} mm high, toe radius {_f(r.base_radius_mm, '.1f')} mm, "
             f"axis at ({r.axis_mm[0]:.1f}, {r.axis_mm[1]:.1f}) mm"]
    cells = [f"{s.azimuth_deg:5.0f}°: {s.angle_deg:5.2f}" for s in r.slices]
    for k in range(0, len(cells), 4):
        lines.append("  " + "   ".join(cells[k:k + 4]))
    lines += [f"  ! {w}" for w in r.warnings]
    if plot and len(r.slices) >= 3:
        lines.append(text_plot([("slice angle", np.array([s.azimuth_deg for s in r.slices]),
                                 np.array([s.angle_deg for s in r.slices]))], width, 6,
                               y_label="angle (deg)", x_label="azimuth (deg)"))
    return "\n".join(lines)


def series_text(r: SeriesResult, width: int = 60, plot: bool = True, rows: int = 12) -> str:
    unit = r.time_unit
    ok = np.isfinite(r.angle_deg)
    head = f"{r.source}: {r.kind}, {ok.sum()} of {len(ok)} samples measured"
    if r.settled is not None:
        s = r.settled
        head += (f"; settled angle {s.angle_deg:.2f} deg (SD {s.sd_deg:.2f}, {s.samples} samples within "
                 f"±{s.tolerance_deg:.2f} deg) from {s.from_s:g} {unit}")
    lines = [head]
    if r.failures:
        lines.append("  not measured: " + ", ".join(f"{k} ({v})" for k, v in r.failures.items()))
    idx = np.unique(np.linspace(0, len(r.time_s) - 1, min(rows, len(r.time_s))).round().astype(int))
    lines.append(f"  {'time (' + unit + ')':>12}  angle   left   right")
    tfmt = "12.0f" if unit == "step" else "12.3f"
    for i in idx:
        lines.append(f"  {r.time_s[i]:{tfmt}}  {_f(r.angle_deg[i]):>5}  {_f(r.left_deg[i]):>5}  "
                     f"{_f(r.right_deg[i]):>5}")
    if plot and ok.sum() >= 2:
        series = [("angle", r.time_s[ok], r.angle_deg[ok])]
        lines.append(text_plot(series, width, 8, y_label="angle (deg)", x_label=f"time ({unit})"))
    return "\n".join(lines)


def folder_text(r: FolderResult) -> str:
    lines = [f"{r.source}: {len(r.angles)} of {len(r.rows)} files measured; mean {r.angle_deg:.2f} deg, "
             f"SD {r.sd_deg:.2f}",
             f"  {'file':<32} {'kind':<6} {'angle':>7} {'±':>6}"]
    for row in r.rows:
        if row["error"]:
            lines.append(f"  {row['file'][:32]:<32} {row['kind']:<6} error: {row['error']}")
        else:
            lines.append(f"  {row['file'][:32]:<32} {row['kind']:<6} {row['angle_deg']:7.2f} {_f(row['sigma_deg']):>6}")
    return "\n".join(lines)


def text(result, width: int = 60) -> str:
    if isinstance(result, ImageResult):
        return image_text(result, width)
    if isinstance(result, DumpResult):
        return dump_text(result, width)
    if isinstance(result, SeriesResult):
        return series_text(result, width)
    if isinstance(result, FolderResult):
        return folder_text(result)
    return f"{result.get('source', 'result')}: angle of repose {result['angle_deg']:.2f} deg (saved result)"


def to_dict(result) -> dict:
    return result if isinstance(result, dict) else result.to_dict()


def plot(result, path: str | Path, image: np.ndarray | None = None) -> Path:
    """A PNG figure of the result: the photo with its outline and fits, the slices, or the series."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(path)
    if isinstance(result, ImageResult):
        fig, ax = plt.subplots(figsize=(10, 5.5), constrained_layout=True)
        o = result.outline
        if image is not None:
            ax.imshow(image[..., ::-1])
        ax.plot(o.x, o.y, "-", color="red", lw=0.8, label="outline")
        for f in result.flanks.values():
            xs = np.array(f.x_range_px)
            ax.plot(xs, f.intercept_px + f.slope * xs, "-", color="cyan", lw=2,
                    label=f"{f.side}: {f.angle_deg:.2f}° ± {f.sigma_deg:.2f}")
        x0, y0, x1, y1 = o.bbox
        pad = 0.08 * max(x1 - x0, y1 - y0)
        ax.set_xlim(x0 - pad, x1 + pad)
        ax.set_ylim(y1 + pad, y0 - pad)
        ax.set_aspect("equal")
        ax.legend(loc="upper right", fontsize=8)
        ax.set_title(f"angle of repose {result.angle_deg:.2f}° ({result.geometry})")
    elif isinstance(result, DumpResult):
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), constrained_layout=True)
        s = result.surface
        axes[0].scatter(s[:, 0], s[:, 1], s=3, c=s[:, 2], cmap="hsv", vmin=0, vmax=360)
        axes[0].set_xlabel("distance from the axis (mm)")
        axes[0].set_ylabel("height above the base (mm)")
        axes[0].set_title(f"surface particles; cone {result.cone_angle_deg:.2f}°")
        for b in result.band:
            axes[0].axhline(b * result.height_mm, color="0.6", lw=0.8, ls="--")
        az = [sl.azimuth_deg for sl in result.slices]
        axes[1].errorbar(az, [sl.angle_deg for sl in result.slices], [sl.sigma_deg for sl in result.slices], fmt="o")
        axes[1].axhline(result.angle_deg, color="k", lw=1)
        axes[1].set_xlabel("slice azimuth (deg)")
        axes[1].set_ylabel("angle (deg)")
        axes[1].set_title(f"mean {result.angle_deg:.2f}° (SD {result.sd_deg:.2f})")
    elif isinstance(result, SeriesResult):
        fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
        ax.plot(result.time_s, result.angle_deg, "o-", ms=3, label="angle")
        if np.isfinite(result.left_deg).any():
            ax.plot(result.time_s, result.left_deg, ".", ms=2, color="tab:green", label="left flank")
            ax.plot(result.time_s, result.right_deg, ".", ms=2, color="tab:red", label="right flank")
        if result.settled is not None:
            st = result.settled
            ax.axhspan(st.angle_deg - st.tolerance_deg, st.angle_deg + st.tolerance_deg, color="0.85")
            ax.axvline(st.from_s, color="k", lw=0.8, ls="--")
            ax.set_title(f"settled {st.angle_deg:.2f}° from {st.from_s:g} {result.time_unit}")
        ax.set_xlabel(f"time ({result.time_unit})")
        ax.set_ylabel("angle (deg)")
        ax.legend(fontsize=8)
    elif isinstance(result, FolderResult):
        fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
        rows = [r for r in result.rows if r["angle_deg"] is not None]
        ax.bar(range(len(rows)), [r["angle_deg"] for r in rows], yerr=[r["sigma_deg"] or 0 for r in rows])
        ax.set_xticks(range(len(rows)), [r["file"] for r in rows], rotation=45, ha="right", fontsize=7)
        ax.axhline(result.angle_deg, color="k", lw=1)
        ax.set_ylabel("angle (deg)")
        ax.set_title(f"mean {result.angle_deg:.2f}° (SD {result.sd_deg:.2f})")
    else:
        raise SandtrackError("a saved result has nothing to plot")
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
