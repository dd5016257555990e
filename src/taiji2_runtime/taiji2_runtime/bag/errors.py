"""The one exception type of the bag tools: a bag that cannot be read or written as asked."""

from __future__ import annotations

from pathlib import Path


class BagError(ValueError):
    """A bad bag or bad bag request; ``str()`` is one line naming the file and the problem.

    Attributes
    ----------
    path : pathlib.Path
        The bag (directory or storage file) concerned.
    problem : str
        What is wrong, without the path.
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = " ".join(str(problem).split())
        # an address (yamcs://...) is named as given: a Path would fold its "//"
        super().__init__(f"{path if '://' in str(path) else self.path}: {self.problem}")
