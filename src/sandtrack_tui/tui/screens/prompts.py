"""Small modal prompts: a line of text, a number, a yes/no question, what to do about unsynced cameras.
Their text wraps to the dialog's width (a Label is as wide as its text unless told otherwise), and a
dialog never grows wider than the terminal."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Label


class AskText(ModalScreen):
    """Ask for a line of text; dismisses with `parse(text)`'s value, or None on Escape. `check(text)`
    returns a problem to show (the answer is then asked again), or None to accept it."""

    DEFAULT_CSS = """
    AskText { align: center middle; }
    AskText > Vertical { width: 60; max-width: 95%; height: auto; border: round $accent; padding: 0 1;
                         background: $surface; }
    AskText Label { width: 100%; }
    """
    BINDINGS = [Binding("escape", "cancel", "cancel")]

    def __init__(self, question: str, default: str = "", check=None, input_type: str = "text"):
        super().__init__()
        self.question, self.default, self.check, self.input_type = question, default, check, input_type

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label(self.question)
            yield Input(value=self.default, type=self.input_type, id="answer")
            yield Label("", id="problem")

    def parse(self, text: str):
        """(value, problem): the answer to dismiss with, or what is wrong with it."""
        return text, self.check(text) if self.check is not None else None

    def on_input_submitted(self, event: Input.Submitted) -> None:
        value, problem = self.parse(event.value.strip())
        if problem:
            self.query_one("#problem", Label).update(f"[red]{problem}[/]")
            return
        self.dismiss(value)

    def action_cancel(self) -> None:
        self.dismiss(None)


class AskNumber(AskText):
    """Ask for an integer (within lo..hi when given); dismisses with it, or None on Escape."""

    def __init__(self, question: str, default: int | None = None, lo: int | None = None, hi: int | None = None):
        super().__init__(question, "" if default is None else str(default), input_type="integer")
        self.lo, self.hi = lo, hi

    def parse(self, text: str):
        try:
            value = int(text)
        except ValueError:
            return None, "type a whole number"
        if (self.lo is not None and value < self.lo) or (self.hi is not None and value > self.hi):
            return None, f"between {self.lo} and {self.hi}"
        return value, None


class Confirm(ModalScreen[bool]):
    DEFAULT_CSS = """
    Confirm { align: center middle; }
    Confirm > Vertical { width: 60; max-width: 95%; height: auto; border: round $warning; padding: 0 1;
                         background: $surface; }
    Confirm Label { width: 100%; }
    """
    BINDINGS = [Binding("y,enter", "yes", "yes"), Binding("n,escape", "no", "no")]

    def __init__(self, question: str):
        super().__init__()
        self.question = question

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label(self.question)
            yield Label("[b]y[/] / enter: yes    [b]n[/] / escape: no")

    def action_yes(self) -> None:
        self.dismiss(True)

    def action_no(self) -> None:
        self.dismiss(False)


class SyncFirst(ModalScreen[str | None]):
    """Tracking asked for while the cameras were never synced: sync now, track anyway, or cancel."""

    DEFAULT_CSS = """
    SyncFirst { align: center middle; }
    SyncFirst > Vertical { width: 76; max-width: 95%; height: auto; border: round $warning; padding: 0 1;
                           background: $surface; }
    SyncFirst Label { width: 100%; }
    SyncFirst #why { margin-bottom: 1; }
    """
    BINDINGS = [Binding("s,enter", "choose('sync')", "sync now"), Binding("t", "choose('anyway')", "track anyway"),
                Binding("escape,c", "choose('')", "cancel")]

    def __init__(self, cameras: str):
        super().__init__()
        self.cameras = cameras

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label(f"[b]The cameras are not synced yet[/] ({self.cameras}). Tracking with an offset of 0 "
                        "pairs frames taken at different times: once the markers move, the stereo check throws "
                        "good views away and markers are lost.", id="why")
            yield Label("[b]s[/] / enter: run the audio sync now, then track")
            yield Label("[b]t[/]: track anyway (cameras that start together)")
            yield Label("[b]escape[/]: cancel")

    def action_choose(self, choice: str) -> None:
        self.dismiss(choice or None)


class AutoSeedChoice(ModalScreen[str | None]):
    """`A`: seed the few markers like the seeded one, or track every particle like it."""

    DEFAULT_CSS = """
    AutoSeedChoice { align: center middle; }
    AutoSeedChoice > Vertical { width: 80; max-width: 95%; height: auto; border: round $accent; padding: 0 1;
                                background: $surface; }
    AutoSeedChoice Label { width: 100%; }
    AutoSeedChoice #title { margin-bottom: 1; }
    """
    BINDINGS = [Binding("m,enter", "choose('markers')", "markers"), Binding("e", "choose('every')", "every particle"),
                Binding("y", "choose('every+new')", "every particle, new ones too"),
                Binding("escape,c", "choose('')", "cancel")]

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label("[b]Auto-seed[/]: what to find like the seeded one?", id="title")
            yield Label("[b]m[/] / enter: the markers like the seeded one (paired across cameras, a list to confirm)")
            yield Label("[b]e[/]: every particle like it, tracked by detection from the seed's frame to the end "
                        "(hundreds, one edit: u undoes); particles entering later are left out")
            yield Label("[b]y[/]: every particle like it, and particles entering later get new ids too")
            yield Label("[b]escape[/]: cancel")

    def action_choose(self, choice: str) -> None:
        self.dismiss(choice or None)
