"""User-facing errors: one clear line, never a traceback."""


class SandtrackError(Exception):
    """An error caused by input the user can fix; the message is shown as one line."""

    def __str__(self) -> str:
        # names read from files (cameras, keys) may hold line breaks: keep the message on one line
        return " ".join(super().__str__().splitlines())


class NotAvailableYet(SandtrackError):
    """A workflow step that this version does not provide."""
