"""Correction actions of the main view; each calls one core function (`corrections`, the store's
undo/redo) and every edit is one undoable entry of the project's edit log."""

from __future__ import annotations

from .. import corrections
from ..errors import SandtrackError
from .screens.prompts import AskNumber


class EditingMixin:
    """Part of SandtrackApp."""

    def _range(self) -> tuple[int, int] | None:
        if self.range_in is None and self.range_out is None:
            return None
        a = self.range_in if self.range_in is not None else self.frame
        b = self.range_out if self.range_out is not None else self.frame
        return (min(a, b), max(a, b))

    def _cam_range(self, camera: str, rng: tuple[int, int]) -> tuple[int, int]:
        return self.cam_index(camera, rng[0]), self.cam_index(camera, rng[1])

    def _need_selected(self) -> int | None:
        if self.selected is None:
            self.notify("select a marker first (1-8)", severity="warning")
        return self.selected

    def _edit(self, fn, message: str | None = None) -> None:
        try:
            result = fn()
        except SandtrackError as exc:
            self.notify(str(exc), severity="error")
            return
        self.after_edit(message(result) if callable(message) else message)

    def action_nudge(self, dx: int, dy: int) -> None:
        m = self._need_selected()
        if m is None:
            return
        cam = self.active

        def fn():
            corrections.nudge(self.project, m, cam, self.cam_index(cam), dx, dy)
            rec = self.project.points(frame=self.cam_index(cam), camera=cam, marker=m).iloc[0]
            self.cursor[cam] = (float(rec.x_px), float(rec.y_px))

        self._edit(fn)

    def action_occlude(self) -> None:
        m = self._need_selected()
        if m is None:
            return
        rng = self._range() or (self.frame, self.frame)
        cam = self.active
        self._edit(lambda: corrections.mark_occluded(self.project, m, cam, self._cam_range(cam, rng)),
                   f"marker {m} marked occluded in {cam}")

    def action_mark_in(self) -> None:
        self.range_in = self.frame
        self.refresh_all()

    def action_mark_out(self) -> None:
        self.range_out = self.frame
        self.refresh_all()

    def action_delete(self) -> None:
        m = self._need_selected()
        if m is None:
            return
        rng = self._range() or (self.frame, self.frame)
        cam = self.active
        self._edit(lambda: corrections.delete_range(self.project, m, cam, self._cam_range(cam, rng)),
                   f"deleted marker {m} in {cam}, frames {rng[0]}-{rng[1]} (u undoes)")

    def action_interpolate(self) -> None:
        m = self._need_selected()
        if m is None:
            return
        cam = self.active
        rng = self._range()
        if rng is None:
            gap = corrections.gap_around(self.project, m, cam, self.cam_index(cam))
            if gap is None:
                self.notify("no gap here: set a range with [ and ], or go into a gap (n)", severity="warning")
                return
            cam_rng = gap
        else:
            cam_rng = self._cam_range(cam, rng)
        self._edit(lambda: corrections.interpolate_gap(self.project, m, cam, cam_rng),
                   lambda n: f"interpolated {n} frames of marker {m} in {cam} (marked 'interpolated')")

    def action_swap(self) -> None:
        m = self._need_selected()
        if m is None:
            return
        rng = self._range() or (self.frame, self.n_frames - 1)

        def done(other):
            if other is None:
                return
            # the range is in side frames: each camera swaps over its own frames, all in one edit
            def fn():
                ranges = {cam: self._cam_range(cam, rng) for cam in self.cameras}
                return corrections.swap_markers(self.project, m, other, ranges)

            self._edit(fn, lambda n: f"swapped markers {m} and {other} over frames {rng[0]}-{rng[1]} ({n} points)")

        self.push_screen(AskNumber(f"Swap marker {m} with which marker, frames {rng[0]}-{rng[1]}?", None, 1, 999),
                         done)

    def action_undo(self) -> None:
        try:
            what = self.project.undo()
        except SandtrackError as exc:
            self.notify(str(exc), severity="error")
            return
        self._after_history(what, "undone")

    def action_redo(self) -> None:
        try:
            what = self.project.redo()
        except SandtrackError as exc:
            self.notify(str(exc), severity="error")
            return
        self._after_history(what, "redone")

    def _after_history(self, what: str | None, verb: str) -> None:
        if what is None:
            self.notify(f"nothing to {verb[:-2]}")
            return
        if what.startswith("set sync_offset_s") or "sync" in what:
            self.apply_sync_offset(self.project.sync_offset_s, save=False)
        if "calibration" in what:
            self._calibration = self._load_calibration()
        self.after_edit(f"{verb}: {what}")
