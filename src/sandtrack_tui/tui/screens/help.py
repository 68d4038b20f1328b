"""`?`: every key binding, grouped, plus tips for SSH and tmux."""

from __future__ import annotations

from rich.console import Group
from rich.table import Table
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Markdown, Static

TIPS = """
### Mouse
- **click** in a view: place the selected marker there (snaps to the blob centre)
- **right-click**: select the marker under the pointer
- **wheel**: zoom about the pointer; **drag**: pan a zoomed view; **click the timeline**: go to that frame

### Markers in a crowd
- An id sits beside its marker, never over another id or marker; where there is no room it moves
  further out with a thin line to its marker.
- **m** lists the markers nearest the cursor first: enter selects, **r** renames, **M** merges two
  ids that are one bead, **/** filters by id or name.
- **A** again keeps the ids of markers the project already has (where they are now, or were last
  seen) and only numbers the new ones.

### Cameras
- One camera: 2D, x and y in mm through a scale: **c** at both ends of a known length (or from a
  calibration of that camera). Three or more: a grid of views; each view shows the selected
  marker's epipolar curves from every other view, in the colour of that view's title.
- Tracking cameras never synced asks first: sync them now (F2's audio sync), track anyway, or cancel.

### Over SSH / tmux
- sshd does not forward `COLORTERM`: start with `COLORTERM=truecolor sandtrack` (otherwise 256 colours).
- tmux: `set -as terminal-features ',*:RGB'` in `~/.tmux.conf` (tmux 3.2+; older: `set -ga
  terminal-overrides ',*:Tc'`). If clicks do nothing in tmux, add `set -g mouse on`; the keys do
  everything the mouse does.
- Every edit is saved at once: a dropped link loses nothing; run `sandtrack PROJECT` again.
"""


class HelpScreen(ModalScreen[None]):
    DEFAULT_CSS = """
    HelpScreen { align: center middle; }
    HelpScreen > VerticalScroll { width: 90%; max-width: 110; height: 90%; border: round $accent;
                                  background: $surface; padding: 0 1; }
    """
    BINDINGS = [Binding("escape,q,question_mark", "close", "close")]

    def __init__(self, groups: list[tuple[str, list[tuple[str, str]]]]):
        super().__init__()
        self.groups = groups

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static(self.key_tables())
            yield Markdown(TIPS)

    def key_tables(self) -> Group:
        parts = []
        for title, rows in self.groups:
            table = Table(title=title, title_justify="left", title_style="bold", box=None, show_header=False,
                          padding=(0, 2, 0, 0), expand=False)
            table.add_column(style="bold cyan", no_wrap=True, min_width=18)
            table.add_column()
            for k, d in rows:
                table.add_row(k, d)
            parts.append(table)
        return Group(*parts)

    def action_close(self) -> None:
        self.dismiss(None)
