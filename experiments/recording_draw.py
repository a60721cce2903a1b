"""Drawing primitives of the rerun recorder (:mod:`experiments.recording`): the timeline's name,
the colours (RGBA, 0-255), entity paths from raw parts, particle shading by weight, colours packed as
``0xRRGGBBAA`` ``uint32`` and :class:`Rows`, one entity's per-update values buffered and written as
columns (one :meth:`rerun.RecordingStream.send_columns` per entity and batch)."""
from __future__ import annotations

import numpy as np
import rerun as rr

TIMELINE = "t"

PINK = (255, 105, 180, 255)
GREEN = (40, 200, 80, 255)
GREEN_SHADE = (40, 200, 80, 70)
ORANGE = (255, 150, 0, 255)
TRUTH_GREY = (150, 150, 150, 255)
FLOOR_GREY = (120, 120, 120, 255)
PARTICLE_LIGHT = np.array([190.0, 215.0, 255.0, 90.0])
PARTICLE_DARK = np.array([20.0, 40.0, 170.0, 255.0])


def path(*parts: str) -> str:
    """An entity path from raw parts (object ids may hold ``/`` or spaces): ``/plots/p_held/cup``."""
    return "/" + "/".join(rr.escape_entity_path_part(p) for p in parts)


def weight_colors(weights: np.ndarray) -> np.ndarray:
    """RGBA ``(K, 4)`` uint8 colours shading normalised particle ``weights (K,)``: light and
    transparent for light particles, dark blue for the heaviest."""
    w = np.asarray(weights, float)
    s = w / w.max() if w.size and w.max() > 0 else np.zeros_like(w)
    return (PARTICLE_LIGHT + s[:, None] * (PARTICLE_DARK - PARTICLE_LIGHT)).astype(np.uint8)


class Rows:
    """Rows of one entity buffered for :meth:`rerun.RecordingStream.send_columns`.

    Each row (one time point) has ``n`` instances; every instance component is given as an array
    ``(n, ...)`` or a list of ``n`` items (a row with ``n = 0`` shows nothing). ``mono`` holds
    components with one value per row (a fill mode), constant for the entity.
    """

    def __init__(self, archetype, **mono):
        self.archetype = archetype
        self.mono = mono
        self.times: list[float] = []
        self.lengths: list[int] = []
        self.parts: dict[str, list] = {}

    def add(self, t: float, n: int, **components) -> None:
        self.times.append(t)
        self.lengths.append(n)
        for name, value in components.items():
            self.parts.setdefault(name, []).append(value)

    def write(self, stream: rr.RecordingStream, entity: str) -> None:
        if not self.times:
            return
        comps = {name: [x for v in vs for x in v] if isinstance(vs[0], list) else np.concatenate(vs)
                 for name, vs in self.parts.items()}
        columns = list(self.archetype.columns(**comps).partition(self.lengths))
        if self.mono:
            columns += list(self.archetype.columns(**{k: [v] * len(self.times) for k, v in self.mono.items()}))
        stream.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=self.times)], columns=columns)
        self.times, self.lengths, self.parts = [], [], {}


def packed(rgba) -> np.uint32:
    """An RGBA colour (0-255 each) as one ``0xRRGGBBAA`` ``uint32``, as rerun stores colours."""
    r, g, b, a = (int(v) for v in rgba)
    return np.uint32((r << 24) | (g << 16) | (b << 8) | a)

