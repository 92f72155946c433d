"""What a session refuses: one exception, its message shown on the page."""


class Refused(ValueError):
    """A drag or submission the session will not take; the message says why (shown on the page)."""
