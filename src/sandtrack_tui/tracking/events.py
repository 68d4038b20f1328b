"""What the engine records for the run's summary besides the points: ambiguities (a blob two tracks
want, several candidates in a gate), once per stretch of consecutive frames, at most `max_events`."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class AmbiguityLog:
    """Ambiguities noted by the step's stages (note), as the run's summary lists them (records)."""

    max_events: int = 500
    records: list = field(default_factory=list)
    _open: dict = field(default_factory=dict)  # (marker, camera) -> its latest record

    def note(self, marker, cam, frame, n, shared=False) -> None:
        """Record an ambiguity once per stretch (consecutive frames extend the same record)."""
        key = (marker, cam)
        rec = self._open.get(key)
        if rec is not None and abs(frame - rec["last_frame"]) <= 1:
            rec["last_frame"] = frame
            rec["candidates"] = max(rec["candidates"], n)
            return
        if len(self.records) >= self.max_events:
            return
        rec = {"marker": marker, "camera": cam, "frame": frame, "last_frame": frame, "candidates": n,
               "why": "blob wanted by two tracks" if shared else "several candidate blobs in the gate"}
        self.records.append(rec)
        self._open[key] = rec
