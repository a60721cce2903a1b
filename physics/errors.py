"""Errors raised for bad user input (scene files, observation streams).

Every error names where the problem is: the file, the line (1-based, when known) and the field, so
that a user never has to read a traceback from inside pybullet to find a typo in a scene file.
"""
from __future__ import annotations


class InputError(ValueError):
    """A malformed input, located by ``path``, ``line`` and ``field``.

    ``str(err)`` reads ``"scene.yaml:12: objects[2].mass: must be > 0, got -1"``.
    """

    def __init__(self, message: str, *, path: str | None = None, line: int | None = None,
                 field: str | None = None):
        self.message = message
        self.path = path
        self.line = line
        self.field = field
        super().__init__(self._format())

    def _format(self) -> str:
        where = ""
        if self.path is not None:
            where = str(self.path)
            if self.line is not None:
                where += f":{self.line}"
            where += ": "
        elif self.line is not None:
            where = f"line {self.line}: "
        if self.field:
            where += f"{self.field}: "
        return where + self.message


class SceneError(InputError):
    """A malformed scene file, or one that names a file that does not exist."""


class ObservationError(InputError):
    """A malformed frame of an observation stream."""


class ConfigError(InputError):
    """A malformed estimator configuration file."""
