"""The files of a simulated run and their number format: ``scene.yaml``, ``observations.jsonl``,
``truth.jsonl`` and ``meta.json`` (:func:`write_outputs`), numbers rounded to :data:`DECIMALS`
decimals so that the same scenario and seed give byte-identical files."""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from physics.scene import Scene, scene_to_dict

FORMAT_VERSION = 1
DECIMALS = 6


def _r(x: float) -> float:
    """Round to :data:`DECIMALS` decimals, without negative zeros."""
    return round(float(x), DECIMALS) + 0.0


def _rl(values) -> list[float]:
    return [_r(v) for v in values]


@dataclass
class SimulationResult:
    """Streams of one run: ``truth`` and ``observations`` (one dict per line of the JSONL files),
    all ``events``, the settled ``initial_poses`` (M, 7), and the per-object ``height_offsets`` (m)
    the tracker applies. :func:`simulate` fills ``scene`` (for scene.yaml) and ``meta``."""

    initial_poses: np.ndarray
    truth: list[dict]
    observations: list[dict]
    events: list[dict]
    warnings: list[str]
    height_offsets: np.ndarray
    scene: Scene | None = None
    meta: dict | None = None


def _round_tree(x):
    if isinstance(x, dict):
        return {k: _round_tree(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_round_tree(v) for v in x]
    if isinstance(x, float):
        return _r(x)
    return x


def _jsonl(rows: list[dict]) -> str:
    return "".join(json.dumps(r, allow_nan=False) + "\n" for r in rows)


def write_outputs(result: SimulationResult, out_dir: str | os.PathLike, *, prefix: str = "") -> dict[str, Path]:
    """Write ``scene.yaml``, ``observations.jsonl``, ``truth.jsonl`` and ``meta.json`` (each name
    preceded by ``prefix``) into ``out_dir`` (created if needed). Returns the paths written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    texts = {
        "scene.yaml": yaml.safe_dump(scene_to_dict(result.scene), sort_keys=False, default_flow_style=None,
                                     width=100),
        "observations.jsonl": _jsonl(result.observations),
        "truth.jsonl": _jsonl(result.truth),
        "meta.json": json.dumps(result.meta, indent=2, allow_nan=False) + "\n",
    }
    paths = {}
    for name, text in texts.items():
        p = out / f"{prefix}{name}"
        with open(p, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        paths[name] = p
    return paths


def read_jsonl(path: str | os.PathLike) -> list[dict]:
    """Read a JSON Lines file written by :func:`write_outputs`."""
    with open(path, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]
