"""The one exception type the CLI turns into a one-line error."""


class CivicError(Exception):
    """A user-facing error: bad input, bad configuration, unreachable switch."""
