"""Seeding and tracking actions of the main view: click or cursor + enter places the selected
marker (snapped to the blob centre), auto-seed with a confirmation list, track forward/backward."""

from __future__ import annotations

import math

import numpy as np

from .. import corrections
from ..errors import NotAvailableYet, SandtrackError
from ..video import synced_camera
from .core import available, core
from .frame_view import FrameView, marker_mask
from .screens.prompts import SyncFirst
from .tasks import guarded

# Workers decode on their own (sequentially); a small cache keeps the app's memory in check.
WORKER_CACHE_MB = 48


class SeedingMixin:
    """Part of SandtrackApp."""

    @guarded
    def on_frame_view_clicked(self, msg: FrameView.Clicked) -> None:
        cam = msg.view.camera
        if cam != self.active:
            self.active = cam
            for v in self.views():
                v.set_class(v.camera == cam, "-active")
        self.cursor[cam] = (msg.x, msg.y)
        if msg.button == 3:
            self._select_near(cam, msg.x, msg.y)
            return
        self.seed_at(cam, msg.x, msg.y)

    def _select_near(self, cam: str, x: float, y: float) -> None:
        best, best_d = None, math.inf
        for rec in self._by_cam_frame.get((cam, self.cam_index(cam)), ()):
            if rec.x_px is None or not np.isfinite(rec.x_px):
                continue
            d = math.hypot(rec.x_px - x, rec.y_px - y)
            if d < best_d:
                best, best_d = int(rec.marker), d
        tf = self.view(cam).tf
        if best is not None and best_d <= max(20.0, 3 * (tf.s if tf else 1.0)):
            self.selected = best
        self.refresh_all()

    def action_seed_cursor(self) -> None:
        x, y = self.cursor[self.active]
        self.seed_at(self.active, x, y)

    def snap(self, camera: str, x: float, y: float) -> tuple[float, float] | None:
        """The marker centroid near (x, y), or None when there is no marker there."""
        tf = self.view(camera).tf
        radius = max(12.0, 2.0 * (tf.s if tf else 1.0))  # a click is good to about ±s
        tracking = core("tracking.run", "snap_to_marker")
        frame = self.sources[camera].frame(self.cam_index(camera))
        return tracking.snap_to_marker(frame, x, y, radius=int(math.ceil(radius)))

    def seed_at(self, camera: str, x: float, y: float) -> None:
        if self.selected is None:
            existing = [m for m, _ in self.marker_list]
            self.selected = next(n for n in range(1, 1000) if n not in existing)
        marker = self.selected
        try:
            snapped = self.snap(camera, x, y)
        except NotAvailableYet as exc:
            self.notify(f"{exc}: placed where clicked", severity="warning")
            snapped = (x, y)
        except SandtrackError as exc:
            self.notify(str(exc), severity="error")
            return
        if snapped is None:
            self.notify(f"no marker found near ({x:.0f}, {y:.0f}) in {camera}: zoom in (+) or try closer",
                        severity="warning")
            self.update_overlays(camera)
            return
        sx, sy = float(snapped[0]), float(snapped[1])
        frame = self.cam_index(camera)
        try:
            corrections.ensure_marker(self.project, marker)
            if available("tracking.run", "seed_marker"):
                core("tracking.run").seed_marker(self.project, marker, camera, frame, sx, sy)
            else:
                corrections.set_manual(self.project, marker, camera, frame, sx, sy)
        except SandtrackError as exc:
            self.notify(str(exc), severity="error")
            return
        self.cursor[camera] = (sx, sy)
        self.set_look(self._look_at(camera, frame, sx, sy))
        self.after_edit(f"marker {marker} placed in {camera} at ({sx:.1f}, {sy:.1f})")

    def _look_at(self, camera: str, frame: int, x: float, y: float):
        """The appearance model of the marker seeded at (x, y), or None: blue paint (what the boost
        shows without a model) or nothing that stands out."""
        if not available("tracking.run", "marker_look"):
            return None
        img = self.sources[camera].frame(frame)
        ix, iy = int(round(x)), int(round(y))
        centre = img[max(iy - 1, 0):iy + 2, max(ix - 1, 0):ix + 2]
        if img.ndim == 3 and img.dtype == np.uint8 and marker_mask(centre).mean() > 127:
            return None
        return core("tracking.run", "marker_look").marker_look(img, x, y)

    def set_look(self, look) -> None:
        """Show markers like `look` in the boost (None: blue markers, the default)."""
        if look is not self.look:
            self.look = look
            self.request_frames()

    def learn_look_from_seeds(self) -> None:
        """The boost's look from the project's last seeded point, learned off the UI thread."""
        seeds = self.points[self.points["status"] == "manual"] if len(self.points) else self.points
        seeds = seeds[seeds["camera"].isin(self.cameras)] if len(seeds) else seeds
        if not len(seeds):
            return
        rec = seeds.iloc[-1]

        def job() -> None:
            try:  # (on failure, or when the app has closed meanwhile, the boost keeps showing blue markers)
                look = self._look_at(str(rec.camera), int(rec.frame), float(rec.x_px), float(rec.y_px))
                if look is not None:
                    self.call_from_thread(self.set_look, look)
            except Exception:  # noqa: BLE001
                return

        self.run_worker(job, thread=True, group="look", exit_on_error=False)

    def after_edit(self, message: str | None = None) -> None:
        self.reload_points()
        self.refresh_all()
        if message:
            self.notify(message, timeout=3)

    def action_auto_seed(self) -> None:
        """Ask: the markers like the seeded one (paired across cameras), or every particle like it."""
        from .screens.prompts import AutoSeedChoice

        def chosen(choice) -> None:
            if choice == "markers":
                self.auto_seed_markers()
            elif choice in ("every", "every+new"):
                self.track_every_particle(new_particles=choice == "every+new")

        self.push_screen(AutoSeedChoice(), chosen)

    def _like(self) -> int | None:
        """The selected marker when it was seeded by hand (its look is the one to find), else None: the
        core then takes the lowest marker seeded by hand."""
        pts = self.points
        if self.selected is None or not len(pts):
            return None
        own = pts[(pts["marker"] == self.selected) & (pts["status"] == "manual")]
        return self.selected if len(own) else None

    def track_every_particle(self, new_particles: bool = False) -> None:
        """Every particle like the seeded one, detected and linked frame by frame from the seed's frame to the
        end in a worker, written as one edit (escape stops it: what was written stays, as that one edit)."""
        try:
            particles = core("tracking.particles", "track_every_particle")
        except NotAvailableYet as exc:
            self.notify(str(exc), severity="warning")
            return
        like = self._like()

        def job(progress, should_stop):
            proj = self._worker_project()
            try:
                return particles.track_every_particle(proj, like=like, new_particles=new_particles,
                                                      progress=progress, should_stop=should_stop)
            finally:
                proj.close()

        self.run_task("tracking every particle", job, on_result=self._every_done)

    def _every_done(self, summary) -> None:
        cams = summary.get("cameras", {}) if isinstance(summary, dict) else {}
        parts = [f"{c}: {v['particles']} particles, frames {v['first_frame']}-{v['last_frame']}, "
                 f"{v['flagged']} flagged" for c, v in cams.items()]
        rows = summary.get("rows_written", 0) if isinstance(summary, dict) else 0
        joins = summary.get("joins") if isinstance(summary, dict) else None
        if joins:
            parts.append(f"{sum(v['gaps_closed'] for v in joins['gaps'].values())} gaps closed")
            if joins.get("pairing"):
                parts.append(f"{joins['pairing']['paired']} paired across the views")
        stopped = "; cancelled, kept what was tracked" if isinstance(summary, dict) and summary.get("stopped") else ""
        self.notify(f"every particle: {rows} points written ({'; '.join(parts)}){stopped}; u undoes it", timeout=8)

    def auto_seed_markers(self) -> None:
        try:
            tracking = core("tracking.run", "auto_seed", "accept_seeds")
        except NotAvailableYet as exc:
            self.notify(str(exc), severity="warning")
            return
        from .screens.autoseed import AutoSeedScreen

        try:
            first, last = self.common_range()
        except SandtrackError as exc:
            self.notify(str(exc), severity="error")
            return
        if not first <= self.frame <= last:
            self.go_to(first if self.frame < first else last)
            self.notify(f"a camera has no frame there: auto-seeding at frame {self.frame}, the "
                        f"{'first' if self.frame == first else 'last'} frame every camera recorded")
        frame = self.frame

        def job(progress, should_stop):
            proj = self._worker_project()
            sources = proj.open_sources(cache_mb=WORKER_CACHE_MB)
            try:
                return tracking.auto_seed(proj, frame, sources=sources)
            finally:
                for src in sources.values():
                    src.close()
                proj.close()

        self.run_task("auto-seed", job,
                      on_result=lambda seeds: self.push_screen(AutoSeedScreen(seeds, self.cameras), self._accept_seeds))

    def _accept_seeds(self, seeds) -> None:
        if seeds is None or len(seeds) == 0:
            return
        try:
            core("tracking.run", "accept_seeds").accept_seeds(self.project, seeds)
        except SandtrackError as exc:
            self.notify(str(exc), severity="error")
            return
        self.after_edit(f"{seeds['marker'].nunique()} markers seeded")
        if self.selected is None and self.marker_list:
            self.selected = self.marker_list[0][0]

    def action_track(self, direction: int, all_markers: int) -> None:
        if self._ask_sync_first(lambda: self.action_track(direction, all_markers)):
            return
        if all_markers:
            markers = None
            what = "all markers"
        else:
            if self.selected is None:
                self.notify("select a marker first (1-8), or press r to track all", severity="warning")
                return
            markers = [self.selected]
            what = f"marker {self.selected}"
        try:
            tracking = core("tracking.run", "track_project")
        except NotAvailableYet as exc:
            self.notify(str(exc), severity="warning")
            return
        start = self.frame
        stop = self.n_frames - 1 if direction > 0 else 0
        d = "forward" if direction > 0 else "backward"

        def job(progress, should_stop):
            proj = self._worker_project()
            sources = proj.open_sources(cache_mb=WORKER_CACHE_MB)
            try:
                return tracking.track_project(proj, markers=markers, start=start, stop=stop, direction=d,
                                              progress=progress, should_stop=should_stop, sources=sources)
            finally:
                for src in sources.values():
                    src.close()
                proj.close()

        self.run_task(f"tracking {what} {d}", job, on_result=self._tracking_done)

    def _ask_sync_first(self, then) -> bool:
        """Cameras never synced: ask (sync now / track anyway / cancel) and run `then` after; True if asked."""
        camera = synced_camera(self.cameras)
        if camera is None or self.unsynced_ok or self.project.sync_confirmed():
            return False

        def chosen(choice) -> None:
            if choice == "anyway":
                self.unsynced_ok = True
                then()
            elif choice == "sync":
                self._sync_then(camera, then)

        self.push_screen(SyncFirst(f"{self.ref} and {camera}"), chosen)
        return True

    def _sync_then(self, camera: str, then) -> None:
        """The audio sync (as F2 runs it), applied as one undoable edit, then `then`."""
        try:
            sync = core("sync", "estimate_offset")
        except NotAvailableYet as exc:
            self.notify(str(exc), severity="warning")
            return
        videos = self.project.videos()
        a, b = videos[self.ref].path, videos[camera].path

        def job(progress, should_stop):
            return sync.estimate_offset(a, b, method="auto")

        def done(res) -> None:
            self.apply_sync_offset(res.offset_s)
            self.notify(f"synced: {res.summary()} (u undoes)", timeout=8)
            then()

        self.run_task("sync", job, on_result=done, refresh_points=False)

    def _tracking_done(self, result) -> None:
        if not isinstance(result, dict):
            self.notify("tracking finished")
            return
        text = f"tracking {result.get('direction', '')}: {result.get('rows_written', 0)} points written"
        if result.get("frames") is not None:
            text += f" over {result['frames']} frames"
        if result.get("stereo"):
            text += " (stereo check on)"
        if result.get("stopped"):
            text += "; cancelled"
        paired = result.get("paired_across_views") or []
        if paired:
            text += f"; {len(paired)} bead(s) seen in one view each made one marker with both views (u undoes the run)"
            renamed = {p["from"]: p["marker"] for p in paired}
            if self.selected in renamed:
                self.selected = renamed[self.selected]
                self.refresh_all()
        problems = result.get("problems") or []
        if problems:
            text += f"; {len(problems)} problem(s): " + "; ".join(map(str, problems[:3]))
        self.notify(text, severity="warning" if problems else "information", timeout=8)
