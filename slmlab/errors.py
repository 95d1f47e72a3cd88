"""The one exception type a user can cause.

Every error that bad input can provoke (a missing file, a malformed CSV, an unknown model name, too few
stage positions, ...) is raised as :class:`SlmlabError`. Its message says what was wrong, where (file,
row, column) and what to do. The command line turns it into exit status 2 and one line on stderr.
"""

from __future__ import annotations


class SlmlabError(Exception):
    """An error caused by the user's input, with a message that names the place and the remedy.

    Parameters
    ----------
    message
        What was wrong and what to do about it.
    path
        The file or folder concerned, if any; prefixed to the message.
    """

    def __init__(self, message: str, path: object | None = None):
        self.path = None if path is None else str(path)
        self.reason = message
        super().__init__(f"{self.path}: {message}" if self.path else message)
