"""``scene-estimator bench --repeat N``: every configuration measured N times, and what the runs agree on.

One run's times on a shared or virtual machine move by tens of per cent from one minute to the next
(docs/results/speed.md), so a target such as "p95 under 120 ms in three runs out of three" needs
the runs, and a figure worth quoting needs their spread. The runs go round by round: every
configuration once, then every configuration again, so that a slow spell of the machine falls on all
of them rather than on one. Each run's row carries its ``run`` number (1 to N); :func:`summarise`
then gives, per configuration, the median and range of each figure over its runs and how many runs
kept up with the stream:

* ``kept_up``: the runs whose real-time factor is above 1 (where the row has one: scenarios, live),
  whose median update is under the reasoning horizon, and whose p95 update is under 1.5 horizons
  (:data:`P95_HORIZONS`): with the default horizon of 80 ms, a median under 80 ms and a p95 under
  120 ms.
"""
from __future__ import annotations

import math
from typing import Callable, Iterable, Iterator, TypeVar

import numpy as np

P95_HORIZONS = 1.5
"""A run keeps up when its p95 update is under this many reasoning horizons (and its median under one)."""

SUMMARY_FIGURES = (("realtime_factor", "real-time factor", "{:.2f}"), ("update_ms_median", "median (ms)", "{:.1f}"),
                   ("update_ms_p95", "p95 (ms)", "{:.1f}"), ("ratio", "ratio", "{:.2f}"),
                   ("latency_ms_p95", "latency p95 (ms)", "{:.1f}"), ("peak_memory_mb", "peak memory (MB)", "{:.0f}"))
"""The figures :func:`summarise` gives the median and range of (those of them the rows have), with
their headings and formats in :func:`summary_table`."""

Item = TypeVar("Item")


def rounds(items: list[Item], measure: Callable[[Item], dict], repeat: int) -> Iterator[dict]:
    """``measure(item)`` for every item, ``repeat`` rounds in turn (every item once per round, in
    the same order); each row gets its round as ``run`` (1 to ``repeat``)."""
    if repeat < 1:
        raise ValueError(f"--repeat must be >= 1, got {repeat}")
    for run in range(1, repeat + 1):
        for item in items:
            yield {**measure(item), "run": run}


def kept_up(row: dict, horizon_s: float) -> bool:
    """Whether one run kept up with its stream: real-time factor above 1 (if the row has one),
    median update under ``horizon_s`` (s) and p95 update under :data:`P95_HORIZONS` of it."""
    rt = row.get("realtime_factor")
    horizon_ms = 1e3 * horizon_s
    return ((rt is None or rt > 1.0) and row["update_ms_median"] < horizon_ms
            and row["update_ms_p95"] < P95_HORIZONS * horizon_ms)


def summarise(rows: Iterable[dict], repeat: int, horizon_s: float) -> list[dict]:
    """Per configuration, from the rows of :func:`rounds` (``repeat`` rounds of the same
    configurations in the same order): the configuration's ``scenario`` or ``objects`` and
    ``particles`` (an adaptive count's as ``auto``), ``runs``, ``kept_up`` (:func:`kept_up` with the
    reasoning horizon ``horizon_s``, s), and for each of :data:`SUMMARY_FIGURES` the rows have,
    ``<figure>`` (the median over the runs), ``<figure>_min`` and ``<figure>_max``."""
    rows = list(rows)
    if repeat < 1 or len(rows) % repeat:
        raise ValueError(f"{len(rows)} rows are not {repeat} rounds of the same configurations")
    per_round = len(rows) // repeat
    out = []
    for j in range(per_round):
        runs = rows[j::per_round]
        label = _configuration(runs[0])
        if any(_configuration(r) != label for r in runs):
            raise ValueError("the rounds do not hold the same configurations in the same order")
        summary = {**label, "runs": len(runs), "kept_up": sum(kept_up(r, horizon_s) for r in runs)}
        for name, _, _ in SUMMARY_FIGURES:
            values = [r[name] for r in runs if isinstance(r.get(name), (int, float))]
            values = [float(v) for v in values if math.isfinite(v)]
            if values:
                summary.update({name: float(np.median(values)), f"{name}_min": min(values),
                                f"{name}_max": max(values)})
        out.append(summary)
    return out


def _configuration(row: dict) -> dict:
    """What a row measured: its ``scenario`` or ``objects``, and its particle count as configured
    (an adaptive count's shown mean and maximum dropped: ``"auto (205, max 1024)"`` -> ``"auto"``)."""
    label = {key: row[key] for key in ("scenario", "objects") if key in row}
    label["particles"] = str(row["particles"]).split(" (")[0]
    return label


def summary_table(summary: list[dict]) -> list[str]:
    """The lines of a Markdown table of :func:`summarise`'s rows: each figure as its median with the
    range over the runs in brackets."""
    if not summary:
        return []
    keys = [k for k in ("scenario", "objects", "particles") if k in summary[0]]
    figures = [f for f in SUMMARY_FIGURES if f[0] in summary[0]]
    head = [{"particles": "K"}.get(k, k) for k in keys] + ["runs", "kept up"] + [f"{h}: median [range]"
                                                                                for _, h, _ in figures]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in summary:
        cells = [str(s[k]) for k in keys] + [str(s["runs"]), f"{s['kept_up']}/{s['runs']}"]
        cells += [f"{fmt.format(s[f])} [{fmt.format(s[f + '_min'])}-{fmt.format(s[f + '_max'])}]" if f in s else ""
                  for f, _, fmt in figures]
        lines.append("| " + " | ".join(cells) + " |")
    return lines
