"""Marker actions of the main view: the marker list (a picker for crowds), rename, merge, and the
px -> mm scale of a one-camera project. Each edit is one core call and one undoable entry."""

from __future__ import annotations

import math

import numpy as np

from .. import corrections
from ..errors import SandtrackError
from ..store import LABEL_MAX
from .core import core
from .screens.picker import MarkerPicker, PickerRow
from .screens.prompts import AskNumber, AskText
from .timeline import PROBLEM_CODES


class MarkersMixin:
    """Part of SandtrackApp."""

    # -- the marker list -------------------------------------------------------------------------
    def picker_rows(self) -> list[PickerRow]:
        """Every marker with its status in each camera at this frame and its distance to the cursor
        in the active view, nearest first (markers without a point there after, by id)."""
        cx, cy = self.cursor[self.active]
        rows = []
        for mid, label in self.marker_list:
            status, dist = {}, math.inf
            for cam in self.cameras:
                rec = self.point(cam, mid)
                status[cam] = rec.status if rec is not None else ""
                if cam == self.active and rec is not None and rec.x_px is not None and np.isfinite(rec.x_px):
                    dist = math.hypot(rec.x_px - cx, rec.y_px - cy)
            problems = sum(int(np.isin(self.codes[(mid, c)], PROBLEM_CODES).sum()) for c in self.cameras
                           if (mid, c) in self.codes)
            rows.append(PickerRow(mid, label, status, dist, problems))
        rows.sort(key=lambda r: (not math.isfinite(r.distance_px), r.distance_px, r.marker))
        return rows

    def action_marker_list(self) -> None:
        if not self.marker_list:
            self.notify("no markers yet: click one, or press A to auto-seed", severity="warning")
            return
        self.push_screen(MarkerPicker(self, self.picker_rows(), self.cameras, self.active), self._picked)

    def _picked(self, marker: int | None) -> None:
        if marker is None:
            return
        self.select_marker(marker)

    def select_marker(self, marker: int) -> None:
        """Select a marker and bring it into every view where it has a point (zoomed views pan to it)."""
        self.selected = marker
        for cam in self.cameras:
            rec = self.point(cam, marker)
            if rec is None or rec.x_px is None or not np.isfinite(rec.x_px):
                continue
            if cam == self.active:
                self.cursor[cam] = (float(rec.x_px), float(rec.y_px))
            tf = self.view(cam).tf
            if tf is not None and self.zoom[cam] > 1 and not tf.contains(rec.x_px, rec.y_px):
                self.center[cam] = (float(rec.x_px), float(rec.y_px))
        self.refresh_all()

    # -- rename, merge -----------------------------------------------------------------------
    def action_rename(self, marker: int | None = None, then=None) -> None:
        m = self._need_selected() if marker is None else marker
        if m is None:
            return
        old = dict(self.marker_list).get(m, str(m))

        def check(text: str) -> str | None:
            if not text or len(text) > LABEL_MAX or not text.isprintable():
                return f"1-{LABEL_MAX} printable characters"
            return None

        def done(label):
            if label is not None and label != old:
                self._edit(lambda: corrections.rename_marker(self.project, m, label),
                           f"marker {m} is now called {label} (u undoes)")
            if then is not None:
                then()

        self.push_screen(AskText(f"New name for marker {old} (id {m}; exports keep the id):", old, check), done)

    def action_merge(self, marker: int | None = None, then=None) -> None:
        m = self._need_selected() if marker is None else marker
        if m is None:
            return
        label = dict(self.marker_list).get(m, str(m))

        def done(keep):
            if keep is not None:
                def fn():
                    n = corrections.merge_markers(self.project, keep, m)
                    self.selected = keep
                    return n

                self._edit(fn, lambda n: f"marker {label} merged into marker {keep} ({n} points taken; u undoes)")
            if then is not None:
                then()

        self.push_screen(AskNumber(f"Marker {label} is the same bead as which marker? (that id stays; {label} "
                                   "goes)", None, 1, 10**9), done)

    # -- one camera: the px -> mm scale -------------------------------------------------------
    def action_scale(self) -> None:
        """First press: one end of a known length at the cursor; second press: the other end, then the
        length in mm."""
        cam = self.active
        first = getattr(self, "_scale_from", None)
        if first is None or first[0] != cam:
            self._scale_from = (cam, self.cursor[cam])
            self.notify("scale: one end marked; move the cursor to the other end of a known length and press c "
                        "again (escape cancels)", timeout=8)
            return
        self._scale_from = None
        p1, p2 = first[1], self.cursor[cam]
        scale = core("scale", "from_length", "set_scale")
        cal_cam = self._calibration.cameras.get(cam) if self._calibration is not None else None

        def check(text: str) -> str | None:
            try:
                scale.from_length(p1, p2, float(text), cal_cam)
            except (ValueError, SandtrackError) as exc:
                return str(exc) if isinstance(exc, SandtrackError) else "type the length in mm"
            return None

        def done(text):
            if text is None:
                return
            length = float(text)
            s = scale.from_length(p1, p2, length, cal_cam)
            source = (f"{length:g} mm between ({p1[0]:.1f}, {p1[1]:.1f}) and ({p2[0]:.1f}, {p2[1]:.1f}) px"
                      + (", undistorted" if cal_cam is not None else ""))
            self._edit(lambda: scale.set_scale(self.project, cam, s, source),
                       f"{cam}: {s:.5g} mm per px (u undoes)")

        dist = math.hypot(p2[0] - p1[0], p2[1] - p1[1])
        self.push_screen(AskText(f"Length between the two ends ({dist:.1f} px apart), in mm:", "", check,
                                 input_type="number"), done)
