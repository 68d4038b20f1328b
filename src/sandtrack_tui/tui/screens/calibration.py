"""Calibration: summary of the project's calibration; calibrate from the ChArUco videos, or load a
calibration.toml."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich import box
from rich.table import Table
from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Button, Footer, Input, Label, Static

from ...calibration.report import camera_parameters
from ...camera import Calibration, euler_angles_deg
from ...errors import SandtrackError
from ..core import core
from .base import TaskScreen


def summary_table(cal: Calibration | None):
    if cal is None:
        return "No calibration yet: calibrate from the board videos below, or load a calibration.toml."
    t = Table(box=box.SIMPLE_HEAD, title="Cameras (rig frame = first camera, mm; ± 1 sd)", title_justify="left")
    for c in ("camera", "lens", "size", "fx", "fy", "cx", "cy", "centre mm", "angles °", "rmse px", "noise x/y px",
              "points' hull %"):
        t.add_column(c, justify="right")
    per_camera = (cal.report or {}).get("per_camera") or {}
    for name, c in cal.cameras.items():
        par = camera_parameters(cal, name)
        rep = per_camera.get(name) or {}
        hull = rep.get("calibrated_region_pct")
        unc = cal.uncertainty.get(name)
        noise = "—" if unc is None or unc.noise_px is None else "/".join(f"{v:.3f}" for v in unc.noise_px)
        if rep.get("misdetected_corners") is not None:
            noise += f"\n{rep['misdetected_corners']} misdetected"  # corners left out of the points
        matrix = [f"{par[p]:.1f}" + (f"\n±{par[p + '_sd_px']:.1f}" if p + "_sd_px" in par else "")
                  for p in ("fx", "fy", "cx", "cy")]
        t.add_row(name, c.lens, f"{c.width}×{c.height}", *matrix, ", ".join(f"{v:.0f}" for v in c.center_mm),
                  ", ".join(f"{v:.1f}" for v in euler_angles_deg(c.R)),
                  "—" if c.rmse_px is None else f"{c.rmse_px:.3f}", noise,
                  "—" if hull is None else f"{hull:.0f}")
    names = list(cal.cameras)
    if len(names) >= 2:
        base = float(np.linalg.norm(cal.cameras[names[0]].center_mm - cal.cameras[names[1]].center_mm))
        t.caption = f"baseline {names[0]}–{names[1]}: {base:.1f} mm"
    w = cal.rig_uncertainty.world_frame_sd() if cal.rig_uncertainty is not None else None
    if w is not None:
        t.caption = ((t.caption + "; ") if t.caption else "") + "world frame ± {} mrad, origin ± {} mm".format(
            " / ".join(f"{v:.2f}" for v in w["rotation_sd_mrad"]), " / ".join(f"{v:.3f}" for v in w["origin_sd_mm"]))
    motion = (cal.report or {}).get("view_motion") or {}
    if motion.get("views"):
        t.caption = ((t.caption + "\n") if t.caption else "") + (
            "board moved between the cameras' exposures ± {:.3f}°, {:.3f} mm (largest axis)".format(
                max(motion["rotation_sd_deg"]), max(motion["translation_sd_mm"])))
    if len(names) >= 2:
        from ...triangulation_sd import sd_holds  # numba's import only when a calibration is shown

        t.caption += "\n" + sd_holds(cal, names, "each tracked point's sd (its match score)")
    scalars = {k: v for k, v in (cal.report or {}).items() if isinstance(v, (int, float, str))}
    if not scalars:
        return t
    r = Table(box=box.SIMPLE_HEAD, title="Report", title_justify="left")
    r.add_column("figure")
    r.add_column("value", justify="right")
    for k, v in scalars.items():
        r.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
    from rich.console import Group

    return Group(t, r)


def guess_inputs(project) -> dict:
    """Calibration videos (one per camera of the project), board and reference next to the
    experiment videos, as the sample lays them out (experiment/ and calibration/ side by side,
    board.toml above): {"videos": {camera: path or ""}, "board": path, "reference": path}."""
    vids = project.videos()
    cameras = [c for c in project.cameras() if c in vids]
    out: dict = {"videos": dict.fromkeys(cameras, ""), "board": "", "reference": ""}
    if not cameras:
        return out
    exp = Path(vids[cameras[0]].path).parent
    for root in (exp.parent / "calibration", exp):
        for cam in cameras:
            for suffix in (".mp4", ".MP4", ".mov"):
                p = root / f"{cam}{suffix}"
                if not out["videos"][cam] and p.is_file() and str(p) != vids[cam].path:
                    out["videos"][cam] = str(p)
        if not out["reference"] and (root / "reference.toml").is_file():
            out["reference"] = str(root / "reference.toml")
    for p in (exp.parent / "board.toml", exp / "board.toml"):
        if not out["board"] and p.is_file():
            out["board"] = str(p)
    return out


class CalibrationScreen(TaskScreen):
    AUTO_FOCUS = "#calibrate"
    BINDINGS = [*TaskScreen.BINDINGS, ("ctrl+r", "go", "calibrate")]

    def action_go(self) -> None:
        self.calibrate()

    def compose(self) -> ComposeResult:
        guess = guess_inputs(self.main.project)
        self.cameras = list(guess["videos"])
        points = self.main.project.path.with_name(self.main.project.path.stem + "_points.csv")
        with VerticalScroll():
            yield Static("Calibration", classes="title")
            yield Static(summary_table(self.main._calibration), id="summary")
            yield Static("[b]Calibrate from the board videos[/] (ChArUco, one video per camera; the sync is found "
                         "from their audio)")
            rows = [(f"video-{k}", f"{cam} video:", f"calibration video of the {cam} camera", guess["videos"][cam])
                    for k, cam in enumerate(self.cameras)]
            rows += [("board", "Board:", "board.toml or Caliscope charuco.toml", guess["board"]),
                     ("reference", "Reference:", "reference.toml (board flat on the sand), optional",
                      guess["reference"]),
                     ("points", "Points CSV:", "write the calibration points here (for training)", str(points))]
            width = max(13, *(len(label) + 1 for _, label, _, _ in rows))
            for key, label, hint, value in rows:
                with Horizontal(classes="row"):
                    yield Label(f"{label:<{width}}")
                    yield Input(value=value, placeholder=hint, id=key, compact=True)
            with Horizontal(classes="row"):
                yield Button("Calibrate", id="calibrate", variant="primary", compact=True)
            yield self.progress_row()
            yield Static("", id="result", classes="result")
            with Horizontal(classes="row"):
                yield Label("Or load:      ")
                yield Input(placeholder="path/to/calibration.toml", id="path", compact=True)
                yield Button("Load", id="load", compact=True)
        yield Footer()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "load":
            self.load()
        else:
            self.calibrate()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id == "path":
            self.load()

    def _value(self, key: str) -> str:
        return self.query_one(f"#{key}", Input).value.strip()

    def calibrate(self) -> None:
        pipeline = core("calibration.pipeline", "calibrate_videos")
        if len(self.cameras) < 2:
            self.notify("calibrating from board videos needs two cameras or more; with one camera, set a px -> mm "
                        "scale from a known length (c), or load a calibration.toml", severity="error")
            return
        videos = {}
        for k, cam in enumerate(self.cameras):
            text = self._value(f"video-{k}")
            videos[cam] = Path(text).expanduser()
            if not text or not videos[cam].exists():
                self.notify(f"{cam} calibration video not found: {videos[cam]}", severity="error")
                return
        if not self._value("board"):
            self.notify("give the board file (board.toml)", severity="error")
            return
        board_path, ref, points = self._value("board"), self._value("reference"), self._value("points")
        main = self.main

        def job(progress, should_stop):
            from ...board import load_board
            from ...calibration.points import write_points
            from ...calibration.world import load_reference

            board = load_board(board_path)
            frame, origin = load_reference(ref) if ref else (None, (0.0, 0.0, 0.0))
            res = pipeline.calibrate_videos(videos, board, reference_frame=frame, origin_mm=origin,
                                            with_points=bool(points),
                                            progress=lambda stage, done, total: progress(done, total, stage))
            proj = main._worker_project()
            try:
                proj.set_calibration(res.calibration)
                proj.set("board", board.to_json_dict(), "set board")
                if points and res.points is not None:
                    write_points(res.points, points)
                    proj.set("calibration_points", points, "remember calibration points")
            finally:
                proj.close()
            return res

        self.query_one("#result", Static).update("[yellow]calibrating… (a minute or two)[/]")
        main.run_task("calibration", job, on_result=self.show_result, refresh_points=False)

    def show_result(self, res) -> None:
        self.main.calibration_changed()
        rep = res.report
        lines = [f"[green]calibrated[/]: reprojection RMSE {rep.get('reprojection_rmse_px', float('nan')):.3f} px"]
        if rep.get("board_rmse_mm") is not None:
            lines.append(f"board geometry RMSE {rep['board_rmse_mm']:.3f} mm")
        if res.points is not None:
            lines.append(f"{len(res.points)} calibration points written (F4 trains on them)")
        lines += [f"[yellow]warning[/]: {w}" for w in res.warnings]
        self.query_one("#result", Static).update("\n".join(lines))
        self.query_one("#summary", Static).update(summary_table(self.main._calibration))

    def load(self) -> None:
        path = Path(self._value("path")).expanduser()
        try:
            cal = Calibration.load(path)
            self.main.project.set_calibration(cal)
        except (SandtrackError, OSError) as exc:
            self.notify(str(exc), severity="error")
            return
        self.main.calibration_changed()
        self.query_one("#summary", Static).update(summary_table(cal))
        self.notify(f"calibration loaded from {path}")
