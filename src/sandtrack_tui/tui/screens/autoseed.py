"""Auto-seed confirmation: the proposed seeds, one row per marker; space toggles, enter accepts."""

from __future__ import annotations

import pandas as pd
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import DataTable, Label


class AutoSeedScreen(ModalScreen[pd.DataFrame | None]):
    DEFAULT_CSS = """
    AutoSeedScreen { align: center middle; }
    AutoSeedScreen > Vertical { width: 90%; max-width: 100; height: auto; max-height: 80%; border: round $accent;
                                background: $surface; padding: 0 1; }
    AutoSeedScreen Label { width: 100%; }
    AutoSeedScreen DataTable { height: auto; max-height: 30; }
    """
    BINDINGS = [Binding("space", "toggle", "use / skip"), Binding("enter", "accept", "accept"),
                Binding("escape", "cancel", "cancel")]

    def __init__(self, seeds: pd.DataFrame, cameras: tuple[str, ...] = ("side", "front")):
        super().__init__()
        self.seeds = seeds if seeds is not None else pd.DataFrame()
        self.cameras = list(cameras)
        self.markers = sorted(self.seeds["marker"].unique().tolist()) if len(self.seeds) else []
        self.use = {m: True for m in self.markers}

    def compose(self) -> ComposeResult:
        with Vertical():
            new = sum(not bool(self.seeds[self.seeds["marker"] == m]["existing"].iloc[0])
                      if "existing" in self.seeds else True for m in self.markers)
            yield Label(f"[b]Auto-seed[/]: {len(self.markers)} markers ({len(self.markers) - new} known: same id, "
                        f"{new} new). space: use / skip, enter: accept, escape: cancel")
            yield DataTable(id="seeds", cursor_type="row")

    def on_mount(self) -> None:
        t = self.query_one(DataTable)
        t.add_column("use", key="use", width=4)
        t.add_column("marker", key="marker", width=6)
        t.add_column("known", key="known", width=10)
        for cam in self.cameras:
            t.add_column(f"{cam[:8]} px", key=cam, width=16)
        t.add_column("epipolar px", key="epi", width=11)
        t.add_column("model, contrast", key="model", width=16)
        for m in self.markers:
            rows = self.seeds[self.seeds["marker"] == m]
            cells = []
            for cam in self.cameras:
                r = rows[rows["camera"] == cam]
                cells.append(f"{r['x_px'].iloc[0]:7.1f},{r['y_px'].iloc[0]:7.1f}" if len(r) else "—")
            epi = rows["epipolar_px"].max() if "epipolar_px" in rows else float("nan")
            epi_txt = Text(f"{epi:.2f}" if epi == epi else "—", style="red" if epi == epi and epi > 2 else "")
            t.add_row(self._mark(m), str(m), self._known(rows), *cells, epi_txt, self._model(rows), key=str(m))
        t.focus()

    @staticmethod
    def _known(rows: pd.DataFrame) -> Text:
        """Whether the proposal is a marker the project has (and how far from where it was), or new."""
        if "existing" not in rows or not bool(rows["existing"].iloc[0]):
            return Text("new", style="green")
        return Text(f"yes {rows['match_px'].iloc[0]:.1f} px", style="dim")

    @staticmethod
    def _model(rows: pd.DataFrame) -> Text:
        """The appearance model the seeds get and their lowest contrast, e.g. "dark 11.2"."""
        if "model" not in rows or not len(rows):
            return Text("—")
        kinds = "/".join(sorted(set(rows["model"].astype(str))))
        c = rows["contrast"].min() if "contrast" in rows else float("nan")
        return Text(f"{kinds} {c:.1f}" if c == c else kinds, style="red" if kinds == "none" else "")

    def _mark(self, m) -> Text:
        return Text("[x]", style="green") if self.use[m] else Text("[ ]", style="dim")

    def action_toggle(self) -> None:
        t = self.query_one(DataTable)
        if not self.markers:
            return
        m = self.markers[t.cursor_row]
        self.use[m] = not self.use[m]
        t.update_cell(str(m), "use", self._mark(m))

    def action_accept(self) -> None:
        keep = [m for m in self.markers if self.use[m]]
        self.dismiss(self.seeds[self.seeds["marker"].isin(keep)] if keep else None)

    def action_cancel(self) -> None:
        self.dismiss(None)

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        self.action_accept()
