"""Files read with their line numbers: YAML (or JSON) parsed into plain data plus a map from each
field's path (``objects[1].mass``) to its line, and validators that raise an
:class:`~physics.errors.InputError` subclass naming the file, the line and the field. Used by the
scene, configuration, observation, scenario and topic readers."""
from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
import yaml

from .errors import InputError, SceneError


def _compose_with_lines(text: str, path: str | None,
                        error_class: type[InputError] = SceneError) -> tuple[Any, dict[str, int]]:
    """Parse YAML ``text``; return the data and a map from field path (``objects[1].mass``) to line."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise error_class(f"invalid YAML/JSON: {problem}", path=path, line=line) from None
    lines: dict[str, int] = {}

    def convert(n: yaml.Node, where: str) -> Any:
        lines[where] = n.start_mark.line + 1
        if isinstance(n, yaml.MappingNode):
            out = {}
            for k, v in n.value:
                key = k.value
                child = f"{where}.{key}" if where else str(key)
                lines[child] = k.start_mark.line + 1
                out[key] = convert(v, child)
            return out
        if isinstance(n, yaml.SequenceNode):
            return [convert(v, f"{where}[{i}]") for i, v in enumerate(n.value)]
        loader = yaml.SafeLoader("")
        try:
            return loader.construct_object(n, deep=True)
        finally:
            loader.dispose()

    if node is None:
        return None, lines
    return convert(node, ""), lines


class _Fields:
    """Validation helpers that raise ``error_class`` (:class:`SceneError`) located at a field."""

    def __init__(self, path: str | None, lines: dict[str, int], error_class: type[InputError] = SceneError):
        self.path = path
        self.lines = lines
        self.error_class = error_class

    def error(self, where: str, message: str) -> InputError:
        probe = where
        while probe and probe not in self.lines:
            probe = probe.rsplit(".", 1)[0] if "." in probe else ""
        return self.error_class(message, path=self.path, line=self.lines.get(probe), field=where or None)

    def number(self, value: Any, where: str, *, positive: bool = False, nonneg: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(where, f"must be a number, got {value!r}")
        x = float(value)
        if not math.isfinite(x):
            raise self.error(where, f"must be finite, got {value!r}")
        if positive and x <= 0:
            raise self.error(where, f"must be > 0, got {value!r}")
        if nonneg and x < 0:
            raise self.error(where, f"must be >= 0, got {value!r}")
        return x

    def vector(self, value: Any, where: str, n: int, *, positive: bool = False) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.error(where, f"must be a list of {n} numbers, got {value!r}")
        return tuple(self.number(v, f"{where}[{i}]", positive=positive) for i, v in enumerate(value))

    def quaternion(self, value: Any, where: str) -> tuple[float, float, float, float]:
        q = np.array(self.vector(value, where, 4))
        n = float(np.linalg.norm(q))
        if n < 1e-9:
            raise self.error(where, "zero-length quaternion (expected x, y, z, w)")
        q = q / n
        if q[3] < 0:
            q = -q
        return tuple(float(v) for v in q)

    def mapping(self, value: Any, where: str) -> dict:
        if not isinstance(value, dict):
            raise self.error(where, f"must be a mapping, got {type(value).__name__}")
        return value

    def only(self, mapping: dict, allowed: set[str], where: str) -> None:
        for key in mapping:
            if key not in allowed:
                sub = f"{where}.{key}" if where else str(key)
                raise self.error(sub, f"unknown field (expected one of: {', '.join(sorted(allowed))})")

    def require(self, mapping: dict, names, where: str) -> None:
        """A located error for the first of ``names`` missing from ``mapping``."""
        for name in names:
            if name not in mapping:
                raise self.error(where, f"missing field '{name}'")


def read_yaml_with_lines(path: str | os.PathLike, what: str = "scene file",
                         error_class: type[InputError] = SceneError) -> tuple[Any, dict[str, int]]:
    """The data of a YAML or JSON file and the line of each field (``objects[1].mass``), or
    ``error_class`` naming the file (``what`` it is) when it is missing, unreadable or malformed."""
    path = str(path)
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise error_class(f"{what} not found", path=path) from None
    except OSError as exc:
        raise error_class(f"cannot read {what}: {exc.strerror}", path=path) from None
    return _compose_with_lines(text, path, error_class)
