"""The one error type of the iCub importer: a bad input file, named with its line."""

from __future__ import annotations

from pathlib import Path


class IcubFileError(ValueError):
    """An iCub skin file is unreadable or inconsistent.

    The message is ``FILE:LINE: problem`` (or ``FILE: problem`` when no single line is at
    fault), so that the command line tool can print it as it is, without a traceback.

    Attributes:
        path: the file at fault.
        line: 1-based line number, or None.
        problem: what is wrong, in words.
    """

    def __init__(self, path: str | Path, line: int | None, problem: str) -> None:
        self.path = str(path)
        self.line = line
        self.problem = problem
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {problem}")
