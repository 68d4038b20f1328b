"""The sandtrack terminal UI: step through the cameras, seed, track, correct, and watch XYZ live.

One view per camera: one camera (2D tracking, mm from a scale), two side by side, three or more
in a grid. Frames are those of the first camera ("side"); every other camera shows its frame
nearest in time (video.camera_offsets, the sync offset).

The app only calls the core (store, video, tracking, corrections, xyz, ...). Decoding and
downscaling run on a feeder thread, tracking/sync/training in Textual thread workers that post
messages; widgets are only touched on the UI thread.
"""

from __future__ import annotations

import math
import re
import time
import traceback
from pathlib import Path

import numpy as np
import pandas as pd
from textual import on
from textual.app import App, ComposeResult, SystemCommand
from textual.containers import Grid, Horizontal
from textual.message import Message
from textual.screen import Screen
from textual.widgets import Footer, Label, ProgressBar, Static

from ..errors import NotAvailableYet, SandtrackError
from ..store import Project
from ..video import FramePair, camera_offsets, common_range, nearest_frames
from .core import core
from .editing import EditingMixin
from .feeder import FrameFeeder, FrameRequest, FrameResult
from .frame_view import BOOST_DENSE_SHARE, CAMERA_RGB, FrameView, MarkerMark, Overlays, ViewTransform
from .keys import ANYWHERE, KEY_DISPLAY, KEYS, bindings
from .markers import MarkersMixin
from .screens.help import HelpScreen
from .screens.prompts import AskNumber, Confirm
from .seeding import SeedingMixin
from .table import MarkerRow, MarkerTable
from .tasks import Task, TasksMixin, guarded
from .termcaps import Graphics
from .tiles import ScreenGraphics
from .timeline import Timeline, next_problem, status_codes

GOOD = ("tracked", "manual", "interpolated", "imported")
MEASURED = ("tracked", "manual", "imported")  # a point seen in the image (not interpolated, not a prediction)
FRAME_CACHE_MB = 320  # decoded frames kept for stepping, shared by the cameras

class TableReady(Message):
    def __init__(self, frame: int, rows, error: str | None = None, request: int = 0) -> None:
        super().__init__()
        self.frame, self.rows, self.error, self.request = frame, rows, error, request


class FrameReady(Message):
    def __init__(self, result: FrameResult) -> None:
        super().__init__()
        self.result = result


class SandtrackApp(TasksMixin, SeedingMixin, EditingMixin, MarkersMixin, App):
    TITLE = "sandtrack"
    CSS = """
    Screen { layout: vertical; }
    #status { height: 1; background: $panel; color: $text; padding: 0 1; }
    #views { height: 1fr; min-height: 6; }
    Grid#views { grid-size: 2; grid-gutter: 0; }
    #task { height: 1; display: none; padding: 0 1; }
    #task.-running { display: block; }
    #task Label { width: auto; margin-right: 1; }
    #task ProgressBar { width: 1fr; }
    Screen.-no-table MarkerTable { display: none; }
    Screen.-views-only MarkerTable, Screen.-views-only Timeline { display: none; }
    """
    BINDINGS = bindings()

    def __init__(self, project: Project | str | Path, colors: str | None = None, prefetch: int = 4,
                 graphics: Graphics | None = None):
        super().__init__()
        self.pixels = ScreenGraphics(self, graphics or Graphics("blocks"))
        self.project = project if isinstance(project, Project) else Project.open(project)
        cams = self.project.cameras()
        if not cams:
            raise SandtrackError(f"{self.project.path}: the project has no video (add one: sandtrack relink "
                                 "PROJECT --side PATH)")
        self.sources = self.project.open_sources(cache_mb=max(FRAME_CACHE_MB / len(cams), 40))
        self.cameras = [c for c in cams if c in self.sources]
        self.ref = self.cameras[0]
        self.offsets = camera_offsets(self.cameras, self.project.sync_offset_s)
        self.n_frames = len(self.sources[self.ref])
        self.frame = 0
        self.selected: int | None = None
        self.active = self.ref
        self.unsynced_ok = False  # "track anyway" was chosen once: not asked again in this session
        self.cursor: dict[str, tuple[float, float]] = {
            c: (self.sources[c].width / 2, self.sources[c].height / 2) for c in self.cameras}
        self.zoom = {c: 1.0 for c in self.cameras}
        self.center: dict[str, tuple[float, float] | None] = {c: None for c in self.cameras}
        self.follow = False
        self.boost = True
        self.look = None  # the markers' appearance model when they are not blue (from a seed), for the boost
        self.range_in: int | None = None
        self.range_out: int | None = None
        self.layout_mode = 0
        self.colors_override = colors
        self.prefetch = prefetch
        self.bg_task: Task | None = None
        self._playing = None
        self._direction = 1
        self._wanted: dict[str, tuple] = {}
        self._step_t0: float | None = None
        self.step_latencies_ms: list[float] = []
        self.points = pd.DataFrame()
        self._by_cam_frame: dict[tuple[str, int], list] = {}
        self.marker_list: list[tuple[int, str]] = []
        self._ref_to: dict[str, np.ndarray | None] = {}
        self._calibration = None
        self._labels: dict[int, str] = {}
        self._xyz_note_shown = False
        self._dense_note_shown = False  # the boost's notice of a dense scene, once a session
        self._xyz_project: Project | None = None
        self._table_busy = False
        self._table_asked = 0  # update_table calls so far: an edit during a computation asks for another
        self._table_after_frames = False
        self.feeder: FrameFeeder | None = None
        self._compute_frame_maps()

    # -- layout ------------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield Static("", id="status")
        views = [FrameView(c, id=self._view_id(c), classes="-active" if c == self.active else None)
                 for c in self.cameras]
        if len(views) <= 2:
            yield Horizontal(*views, id="views")
        else:
            grid = Grid(*views, id="views")
            grid.styles.grid_size_columns = 2 if len(views) <= 4 else 3
            yield grid
        yield Timeline(id="timeline")
        yield MarkerTable(self.cameras, id="table")
        with Horizontal(id="task"):
            yield Label("", id="task-label")
            yield ProgressBar(id="task-bar", show_eta=True)
        yield Footer()

    def on_mount(self) -> None:
        # Widgets of the main screen, kept so that workers' messages reach them under other screens.
        self._main_screen = self.screen
        self._w = {w.id: w for w in self.screen.query("*") if w.id}
        colors = self.colors_override or (self.console.color_system or "256")
        for v in self.views():
            v.color_mode = "truecolor" if colors == "truecolor" else "256"
            if len(self.cameras) > 2:  # the colour of the curves this camera casts into the other views
                r, g, b = self._camera_rgb(v.camera)
                v.border_title = f"[rgb({r},{g},{b})]{v.camera}[/]"
            else:
                v.border_title = v.camera
        if colors != "truecolor":
            self.notify("256 colours: the frames are drawn in grey (markers in blue). For colour, start with "
                        "COLORTERM=truecolor (ssh does not pass it on); in tmux also set "
                        "terminal-features ',*:RGB'.", timeout=12)
        self.pixels.start(self.views())
        self.feeder = FrameFeeder(self.sources, lambda r: self.post_message(FrameReady(r)), self.prefetch)
        if self.size.height < 40:
            self._set_layout(1)
        self._calibration = self._load_calibration()
        self.reload_points()
        if self.marker_list:
            self.selected = self.marker_list[0][0]
        self.call_after_refresh(self.refresh_all)
        self.learn_look_from_seeds()
        todo = []
        if len(self.cameras) > 1 and not self.project.sync_confirmed():
            todo.append("the cameras are not synced yet (F2)")
        if self._calibration is None and len(self.cameras) > 1:
            todo.append("no calibration yet, so no XYZ or stereo check (F3)")
        if len(self.cameras) == 1 and self._scale() is None:
            todo.append("one camera: set a px -> mm scale from a known length (c), or add a calibration (F3)")
        if todo:
            self.notify("; ".join(todo) + ". ? shows every key.", timeout=10)
        warnings = [w for c in self.cameras[1:] for w in FramePair(
            self.sources[self.ref], self.sources[c], names=(self.ref, c)).mismatch_warnings()]
        if warnings:
            self.notify("; ".join(warnings), severity="warning", timeout=8)

    def on_unmount(self) -> None:
        # Quitting or a dropped link: a running task stops at its next check (what it wrote is kept),
        # so the process does not linger until a long tracking run ends.
        if self.bg_task is not None:
            self.bg_task.cancel_requested = True
        if self.feeder is not None:
            self.feeder.stop()

    # -- real pixels (kitty graphics / sixel): tiles.py does the work ---------------------------
    def write_graphics(self, data: str) -> None:
        """Escape codes straight to the terminal, in order with the UI's own output (the driver's
        writer thread); nothing in a headless run."""
        driver = self._driver
        if driver is not None and not self.is_headless:
            driver.write(data)
            driver.flush()

    def exit(self, *args, **kwargs) -> None:
        if hasattr(self, "_w"):  # kitty's images leave with the app, while its screen is still up
            self.pixels.stop(self.views())
        super().exit(*args, **kwargs)

    def _display(self, screen: Screen, renderable) -> None:
        # Textual's write of a screen update: a private hook, the only place that knows which cells
        # were written (sixel pictures under them are drawn again right after the text)
        super()._display(screen, renderable)
        if hasattr(self, "_w"):
            self.pixels.after_display(self.views(), renderable, self.screen is self._main_screen)

    def views(self) -> list[FrameView]:
        return [self._w[self._view_id(c)] for c in self.cameras]

    def view(self, camera: str) -> FrameView:
        return self._w[self._view_id(camera)]

    def _view_id(self, camera: str) -> str:
        if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_-]*", camera):
            return f"view-{camera}"
        return f"view-{self.cameras.index(camera)}"

    def _camera_rgb(self, camera: str) -> tuple[int, int, int]:
        return CAMERA_RGB[self.cameras.index(camera) % len(CAMERA_RGB)]

    def on_resize(self, event) -> None:
        self.call_after_refresh(self.request_frames)

    @on(FrameView.Resized)
    @guarded
    def _view_resized(self) -> None:
        self.request_frames()

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if action in ANYWHERE or not hasattr(self, "_main_screen"):
            return True
        return self.screen is self._main_screen

    def report_error(self, exc: BaseException) -> None:
        self.log.error("".join(traceback.format_exception(exc)))
        message = str(exc) if isinstance(exc, SandtrackError) else f"{type(exc).__name__}: {exc}"
        self.notify(message, severity="error", timeout=10)

    # -- frame bookkeeping -------------------------------------------------------------------
    def _compute_frame_maps(self) -> None:
        ref = self.sources[self.ref]
        self._ref_to = {c: None if c == self.ref else nearest_frames(ref, self.sources[c], self.offsets[c])
                        for c in self.cameras}

    def cam_index(self, camera: str, frame: int | None = None) -> int:
        f = self.frame if frame is None else frame
        m = self._ref_to.get(camera)
        return f if m is None else int(m[f])

    def common_range(self) -> tuple[int, int]:
        """First and last frames every camera recorded."""
        return common_range(self.sources, self.offsets, self.ref)

    def _load_calibration(self):
        try:
            return self.project.calibration()
        except SandtrackError as exc:
            self.notify(f"calibration unreadable: {exc}", severity="warning")
            return None

    def reload_points(self) -> None:
        self.points = self.project.points()
        by_cam_frame: dict[tuple[str, int], list] = {}
        for rec in self.points.itertuples(index=False):
            by_cam_frame.setdefault((rec.camera, rec.frame), []).append(rec)
        self._by_cam_frame = by_cam_frame
        labels = dict(self.project.markers()[["id", "label"]].itertuples(index=False, name=None))
        ids = sorted(set(labels) | set(self.points["marker"].unique().tolist() if len(self.points) else []))
        self.marker_list = [(int(m), str(labels.get(m, m))) for m in ids]
        self._labels = dict(self.marker_list)
        groups = {(int(k[0]), str(k[1])): g for k, g in self.points.groupby(["marker", "camera"])} \
            if len(self.points) else {}
        codes = {}
        empty = self.points.iloc[:0]
        for mid, _ in self.marker_list:
            for cam in self.cameras:
                codes[(mid, cam)] = status_codes(groups.get((mid, cam), empty), None, None, self.n_frames,
                                                 self._ref_to[cam])
        self.codes = codes
        self._w['timeline'].set_data(self.marker_list, codes, self.n_frames, self.cameras)

    def point(self, camera: str, marker: int, frame: int | None = None):
        for rec in self._by_cam_frame.get((camera, self.cam_index(camera, frame)), ()):
            if rec.marker == marker:
                return rec
        return None

    # -- rendering ---------------------------------------------------------------------------
    def _transform(self, camera: str) -> ViewTransform | None:
        v = self.view(camera)
        cols, rows = v.content_size.width, v.content_size.height
        if cols < 2 or rows < 1:
            return None
        src = self.sources[camera]
        return ViewTransform.make(src.width, src.height, cols, rows, self.zoom[camera], self.center[camera])

    def request_frames(self) -> None:
        if self.feeder is None:
            return
        for cam in self.cameras:
            if self.follow and self.selected is not None:
                rec = self.point(cam, self.selected)
                if rec is not None and np.isfinite(rec.x_px):
                    self.center[cam] = (float(rec.x_px), float(rec.y_px))
            tf = self._transform(cam)
            if tf is None:
                continue
            req = FrameRequest(cam, self.cam_index(cam), tf, self.boost, self.pixels.cell_px, self.look,
                               self._tracked_at(cam) if self.boost else ())
            self._wanted[cam] = req.key
            v = self.view(cam)
            if v.pixels_key == req.key:
                self.update_overlays(cam)
                continue
            self.feeder.request(req, self._direction)

    def _tracked_at(self, camera: str) -> tuple:
        """(x, y) of the markers measured in this camera at its current frame: in a dense scene the
        marker boost paints these only."""
        return tuple((round(float(rec.x_px), 1), round(float(rec.y_px), 1))
                     for rec in self._by_cam_frame.get((camera, self.cam_index(camera)), ())
                     if rec.status in MEASURED and rec.x_px is not None and np.isfinite(rec.x_px))

    @on(FrameReady)
    @guarded
    def _frame_ready(self, msg: FrameReady) -> None:
        r = msg.result
        cam = r.request.camera
        if self._wanted.get(cam) != r.request.key:
            return
        v = self.view(cam)
        if r.error:
            v.show_message(r.error)
            self.notify(r.error, severity="error")
            return
        if r.boost_limited and not self._dense_note_shown:
            self._dense_note_shown = True
            self.notify(f"marker boost: {r.marker_share:.0%} of the {cam} view looks like markers, so it paints "
                        f"only the tracked markers, and none where they would cover over {BOOST_DENSE_SHARE:.0%} "
                        "of the view (b: boost off)", timeout=8)
        v.pixels, v.pixels_key, v.tf = r.pixels, r.request.key, r.request.tf
        self.update_overlays(cam)
        if self.views_ready():
            if self._step_t0 is not None:
                self.step_latencies_ms.append((time.perf_counter() - self._step_t0) * 1000)
                self._step_t0 = None
            if self._table_after_frames:
                self._table_after_frames = False
                self.call_after_refresh(self.update_table)

    def views_ready(self) -> bool:
        return all(self.view(c).pixels_key == self._wanted.get(c) and c in self._wanted for c in self.cameras)

    def update_overlays(self, camera: str | None = None) -> None:
        for cam in [camera] if camera else self.cameras:
            v = self.view(cam)
            if v.tf is None:
                continue
            shown = v.pixels_key[0] if v.pixels_key else self.cam_index(cam)
            ov = Overlays()
            for rec in self._by_cam_frame.get((cam, shown), ()):
                label = self._labels.get(rec.marker, str(rec.marker))
                x = float(rec.x_px) if rec.x_px is not None else math.nan
                y = float(rec.y_px) if rec.y_px is not None else math.nan
                ov.marks.append(MarkerMark(int(rec.marker), label, x, y, rec.status, rec.marker == self.selected))
            if cam == self.active:
                ov.cursor = self.cursor[cam]
            ov.search = self._search_window(cam)
            ov.epipolar = self._epipolar(cam)
            v.overlays = ov
            v.recompose()

    def _search_window(self, camera: str):
        """Where the tracker will look in the next frame: the tracker's own constant-velocity Kalman
        filter run over the selected marker's last points, its prediction and 99 % gate."""
        if self.selected is None:
            return None
        idx = self.cam_index(camera)
        recent = []
        for f in range(max(idx - 11, 0), idx + 1):
            for rec in self._by_cam_frame.get((camera, f), ()):
                if rec.marker == self.selected and rec.status in GOOD and rec.x_px is not None:
                    recent.append(rec)
        if not recent or recent[-1].frame != idx:
            return None
        try:
            kalman = core("tracking.kalman", "ConstantVelocityKF")
            params = core("tracking.tracker", "TrackParams").TrackParams()
        except NotAvailableYet:
            return None
        kf = kalman.ConstantVelocityKF(float(recent[0].x_px), float(recent[0].y_px), params.accel_px, params.meas_px)
        prev = int(recent[0].frame)
        for r in recent[1:]:
            for _ in range(int(r.frame) - prev):
                kf.predict()
            kf.update((float(r.x_px), float(r.y_px)))
            prev = int(r.frame)
        kf.predict()
        hx, hy = kf.gate_halfsize(params.gate_d2)
        cap = params.max_search_px
        px, py = kf.position
        return (float(px), float(py), min(hx, cap), min(hy, cap))

    def _epipolar(self, camera: str) -> list:
        """The selected marker's epipolar curves in this view: one from every other view where it has a
        point, in that view's colour (where the curves cross is where the marker must be)."""
        cal = self._calibration
        if cal is None or self.selected is None or camera not in cal.cameras:
            return []
        from ..epipolar import epipolar_curve

        curves = []
        for other in self.cameras:
            if other == camera or other not in cal.cameras:
                continue
            rec = self.point(other, self.selected)
            if rec is None or rec.x_px is None or not np.isfinite(rec.x_px):
                continue
            curves.append((epipolar_curve(cal, other, (rec.x_px, rec.y_px), camera), self._camera_rgb(other)))
        return curves

    def refresh_all(self) -> None:
        self.request_frames()
        self.update_status()
        self._w['timeline'].set_position(self.frame, self.selected, (self.range_in, self.range_out))
        # The table (XYZ for this frame) waits for the frames: on a step the picture comes first.
        if self.views_ready():
            self.update_table()
        else:
            self._table_after_frames = True

    def update_status(self) -> None:
        t = float(self.sources[self.ref].times_s[self.frame])
        others = []
        for c in self.cameras[1:]:
            src = self.sources[c]
            tc = t - self.offsets[c]
            j = src.index_at(tc)
            rem = (tc - float(src.times_s[j])) * src.fps
            others.append(f"{c} {j} ({rem:+.2f})" if abs(rem) <= 0.5 else f"{c} [red]not recording[/]")
        front = "  ".join(others)
        sel = "none" if self.selected is None else dict(self.marker_list).get(self.selected, str(self.selected))
        rng = ""
        if self.range_in is not None or self.range_out is not None:
            a = "" if self.range_in is None else self.range_in
            b = "" if self.range_out is None else self.range_out
            rng = f"  range \\[{a}..{b}]"
        zoom = f"  zoom {self.zoom[self.active]:g}x" + (" follow" if self.follow else "")
        play = "  ▶" if self._playing else ""
        self._w['status'].update(
            f"[b]{self.project.path.stem}[/]  frame [b]{self.frame}[/]/{self.n_frames - 1}  t={t:.3f} s  "
            f"{front + '  ' if front else ''}marker [b]{sel}[/]  view [b]{self.active}[/]"
            f"{rng}{zoom}{play}", layout=False)

    def update_table(self) -> None:
        """Recompute the table for the current frame in a worker (XYZ may take tens of ms): at most
        one computation runs; when it ends, the latest frame asked for is computed next (again after an
        edit made while it ran: its rows read the points from before the edit)."""
        if self.layout_mode != 0:
            return
        self._table_asked += 1
        if self._table_busy:
            return
        self._table_busy = True
        frame, request = self.frame, self._table_asked

        def job() -> None:
            try:
                rows = self.table_rows(frame, self._table_project())
                self.post_message(TableReady(frame, rows, request=request))
            except Exception as exc:  # noqa: BLE001 - shown, never fatal
                self.post_message(TableReady(frame, None, f"{type(exc).__name__}: {exc}", request))

        self.run_worker(job, thread=True, group="table", exit_on_error=False)

    def _table_project(self) -> Project:
        if self._xyz_project is None:
            self._xyz_project = Project.open(self.project.path)
        return self._xyz_project

    @on(TableReady)
    @guarded
    def _table_ready(self, msg: TableReady) -> None:
        self._table_busy = False
        if msg.error and not self._xyz_note_shown:
            self._xyz_note_shown = True
            self.notify(f"table: {msg.error}", severity="warning")
        if msg.rows is not None and msg.frame == self.frame:
            self._w['table'].set_rows(msg.rows, self.selected)
        if self._table_asked != msg.request:  # another frame or an edit since this one was asked for
            self.update_table()

    def table_rows(self, frame: int | None = None, project: Project | None = None) -> list[MarkerRow]:
        frame = self.frame if frame is None else frame
        rows = []
        for mid, label in self.marker_list:
            r = MarkerRow(mid, label)
            for cam in self.cameras:
                p = self.point(cam, mid, frame)
                if p is None:
                    continue
                r.status[cam] = p.status
                r.px[cam] = (p.x_px, p.y_px) if p.x_px is not None else None
                if r.score is None or (p.score is not None and p.score < r.score):
                    r.score = p.score
            rows.append(r)
        self._fill_xyz(rows, frame, project or self.project)
        return rows

    def _fill_xyz(self, rows: list[MarkerRow], frame: int, project: Project) -> None:
        """XYZ by triangulation over every camera and by the network (side and front pixels), or x, y
        in mm through the scale (one camera)."""
        if not rows:
            return
        by_id = {r.marker: r for r in rows}
        if len(self.cameras) == 1:
            self._fill_scaled(rows, project)
            return
        if self._calibration is None and not project.get("model"):
            return
        try:
            xyz = core("xyz", "xyz_at_frame").xyz_at_frame(project, frame)
        except SandtrackError:  # e.g. a model file that moved: the table shows no XYZ
            return
        for rec in xyz.itertuples(index=False):
            r = by_id.get(int(rec.marker))
            if r is None:
                continue
            val = (rec.X_mm, rec.Y_mm, rec.Z_mm)
            sd = (rec.sd_X_mm, rec.sd_Y_mm, rec.sd_Z_mm)
            r.nearest_frame = r.nearest_frame or getattr(rec, "xyz_source", "") == "nearest_frame"
            r.outside_region = r.outside_region or getattr(rec, "calibrated_region", "") == "outside"
            if str(rec.method).lower().startswith("tri"):
                r.xyz_tri, r.sd_tri = val, sd
                r.residual_px = rec.residual_px
            else:
                r.xyz_net, r.sd_net = val, sd
                r.net_check = str(getattr(rec, "network_check", "") or "")

    def _scale(self, project: Project | None = None):
        """(mm per px, source) of a one-camera project, or None."""
        return core("scale", "project_scale").project_scale(project or self.project, self.ref, self._calibration)

    def _fill_scaled(self, rows: list[MarkerRow], project: Project) -> None:
        found = self._scale(project)
        if found is None:
            return
        scale = core("scale", "to_mm")
        cam = self._calibration.cameras.get(self.ref) if self._calibration is not None else None
        for r in rows:
            px = r.px.get(self.ref)
            if px is not None:
                r.xy_mm = tuple(scale.to_mm([px], found[0], cam)[0])

    # -- navigation --------------------------------------------------------------------------
    def go_to(self, frame: int) -> None:
        frame = int(np.clip(frame, 0, self.n_frames - 1))
        self._direction = 1 if frame >= self.frame else -1
        if frame == self.frame:
            return
        self.frame = frame
        self._step_t0 = time.perf_counter()
        self.refresh_all()

    def action_step(self, n: int) -> None:
        self.go_to(self.frame + n)

    def action_go(self, frame: int) -> None:
        self.go_to(self.n_frames - 1 if frame < 0 else frame)

    def action_goto(self) -> None:
        def done(v):
            if v is not None:
                self.go_to(v)

        self.push_screen(AskNumber(f"Go to frame (0-{self.n_frames - 1}):", self.frame, 0, self.n_frames - 1), done)

    def action_play(self) -> None:
        if self._playing is not None:
            self._playing.stop()
            self._playing = None
        else:
            self._playing = self.set_interval(1 / 25, self._play_tick)
        self.update_status()

    def _play_tick(self) -> None:
        if not self.views_ready():
            return  # never queue frames faster than they are shown
        if self.frame >= self.n_frames - 1:
            self.action_play()
            return
        self.frame += 1
        self._direction = 1
        self.request_frames()
        self.update_status()
        self._w['timeline'].set_position(self.frame, self.selected, (self.range_in, self.range_out))
        self.update_table()  # coalesced: computes the latest frame whenever the previous one is done

    def action_problem(self, direction: int) -> None:
        codes = self.codes if self.selected is None else {
            k: v for k, v in self.codes.items() if k[0] == self.selected} or self.codes
        f = next_problem(codes, self.frame, direction)
        if f is None:
            self.notify("no more problems in that direction" + ("" if self.selected is None else
                                                               f" for marker {self.selected}"))
            return
        self.go_to(f)

    # -- markers, cursor, views --------------------------------------------------------------
    def action_select(self, n: int) -> None:
        self.selected = n
        rec = self.point(self.active, n)
        if rec is not None and rec.x_px is not None and np.isfinite(rec.x_px):
            self.cursor[self.active] = (float(rec.x_px), float(rec.y_px))
        if n not in dict(self.marker_list):
            self.notify(f"marker {n} is new: click it or move the cursor onto it and press enter")
        self.refresh_all()

    def action_switch_view(self) -> None:
        self.active = self.cameras[(self.cameras.index(self.active) + 1) % len(self.cameras)]
        for v in self.views():
            v.set_class(v.camera == self.active, "-active")
        self.update_overlays()
        self.update_status()

    def action_cursor(self, dx: int, dy: int, k: int) -> None:
        v = self.view(self.active)
        s = v.tf.s if v.tf else 1.0
        src = self.sources[self.active]
        x, y = self.cursor[self.active]
        x = float(np.clip(x + dx * k * s, 0, src.width - 1))
        y = float(np.clip(y + dy * k * s, 0, src.height - 1))
        self.cursor[self.active] = (x, y)
        if v.tf is not None and self.zoom[self.active] > 1 and not v.tf.contains(x, y):
            self.center[self.active] = (x, y)
            self.follow = False
            self.request_frames()
        self.update_overlays(self.active)

    def action_zoom(self, factor: float) -> None:
        cam = self.active
        self.zoom[cam] = float(np.clip(self.zoom[cam] * factor, 1.0, 64.0))
        self.center[cam] = self.cursor[cam]
        self.request_frames()
        self.update_status()

    def action_zoom_fit(self) -> None:
        self.follow = False
        for c in self.cameras:
            self.zoom[c], self.center[c] = 1.0, None
        self.request_frames()
        self.update_status()

    def action_zoom_marker(self) -> None:
        if self.follow:
            self.action_zoom_fit()
            return
        if self.selected is None:
            self.notify("select a marker first (1-8)", severity="warning")
            return
        self.follow = True
        for c in self.cameras:
            self.zoom[c] = max(self.zoom[c], 8.0)
        self.request_frames()
        self.update_status()

    def action_toggle_boost(self) -> None:
        self.boost = not self.boost
        self.notify(f"marker boost {'on' if self.boost else 'off'}")
        self.request_frames()

    def _set_layout(self, mode: int) -> None:
        self.layout_mode = mode
        self._main_screen.set_class(mode == 1, "-no-table")
        self._main_screen.set_class(mode == 2, "-views-only")

    def action_cycle_layout(self) -> None:
        self._set_layout((self.layout_mode + 1) % 3)
        self.update_table()
        self.call_after_refresh(self.request_frames)

    @on(FrameView.Zoom)
    @guarded
    def _wheel_zoom(self, msg: FrameView.Zoom) -> None:
        cam = msg.view.camera
        self.zoom[cam] = float(np.clip(self.zoom[cam] * msg.factor, 1.0, 64.0))
        self.center[cam] = (msg.x, msg.y)
        self.follow = False
        self.request_frames()
        self.update_status()

    @on(FrameView.Pan)
    @guarded
    def _drag_pan(self, msg: FrameView.Pan) -> None:
        cam = msg.view.camera
        tf = msg.view.tf
        if tf is None or self.zoom[cam] <= 1.0:
            return
        cx, cy = tf.center if self.center[cam] is None else self.center[cam]
        self.center[cam] = (cx + msg.dx, cy + msg.dy)
        self.follow = False
        self.request_frames()

    @on(Timeline.Seek)
    @guarded
    def _timeline_seek(self, msg: Timeline.Seek) -> None:
        if msg.marker is not None:
            self.selected = msg.marker
        if msg.frame != self.frame:
            self.go_to(msg.frame)
        else:
            self.refresh_all()

    # -- screens -----------------------------------------------------------------------------
    def apply_sync_offset(self, offset_s: float, save: bool = True) -> None:
        if save:
            self.project.set("sync_offset_s", float(offset_s), f"set sync offset to {offset_s * 1000:.2f} ms")
        self.offsets = camera_offsets(self.cameras, float(offset_s))
        self._compute_frame_maps()
        self.reload_points()
        self.refresh_all()

    def calibration_changed(self) -> None:
        self._calibration = self._load_calibration()
        self.refresh_all()

    def action_screen(self, name: str) -> None:
        from .screens import open_screen

        try:
            screen = open_screen(name, self)
        except NotAvailableYet as exc:
            self.notify(str(exc), severity="warning")
            return
        self.push_screen(screen)

    def action_help(self) -> None:
        groups: dict[str, list[tuple[str, str]]] = {}
        for keys, _action, desc, group, _show in KEYS:
            shown = " ".join(KEY_DISPLAY.get(k, k) for k in keys.split(","))
            groups.setdefault(group, []).append((shown, desc))
        self.push_screen(HelpScreen(list(groups.items())))

    def get_system_commands(self, screen: Screen):
        yield from super().get_system_commands(screen)
        for keys, action, desc, _group, _show in KEYS:
            if not action or action in ("help", "quit"):
                continue
            yield SystemCommand(desc[0].upper() + desc[1:], f"key: {keys.split(',')[0]}",
                                lambda a=action: self.run_action(a))

    async def action_quit(self) -> None:
        if self.bg_task is not None:
            def done(ok):
                if ok:
                    self.bg_task.cancel_requested = True
                    self.exit()

            self.push_screen(Confirm(f"{self.bg_task.name} is running; quit anyway? (points so far are saved)"), done)
            return
        self.exit()


for _cls in SandtrackApp.__mro__:
    if _cls.__module__.startswith(__package__):
        for _name, _fn in list(vars(_cls).items()):
            if _name.startswith("action_") and callable(_fn) and _name in vars(_cls):
                setattr(_cls, _name, guarded(_fn))
