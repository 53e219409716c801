"""One exception type for every problem a user can fix.

The CLI turns an :class:`IsplatError` into one line on stderr and a non-zero exit;
library callers get an ordinary exception with the same message.
"""


class IsplatError(Exception):
    """A problem with the user's input: the message names the file, key, value and what was expected."""

    exit_code = 2


def fail(message: str) -> "NoReturn":  # noqa: F821 - typing only
    """Raise :class:`IsplatError` with ``message``."""
    raise IsplatError(message)
