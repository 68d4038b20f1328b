"""User-facing errors: one clear line, never a traceback."""


class SandtrackError(Exception):
    """An error caused by input the user can fix; the message is shown as one line."""


class NotAvailableYet(SandtrackError):
    """A workflow step that this version does not provide."""
