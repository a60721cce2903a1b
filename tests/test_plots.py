"""Figures of experiments.evaluation.plots on a real short trial and on hand-made rows."""
from __future__ import annotations

import matplotlib.image as mpimg
import numpy as np
import pytest

from experiments.evaluation import plots
from experiments.evaluation.summary import summarize
from experiments.evaluation.trials import TrialSpec, run_trial


@pytest.fixture(scope="module")
def traces():
    """Traces of a 2 s cup_falls_behind_box run for the three main methods (K = 4)."""
    out = {}
    for method, k in (("last-seen", 0), ("paper", 1), ("particles", 4)):
        out[method] = run_trial(TrialSpec("cup_falls_behind_box", 0, method, k, 2.0, trace=True))
    return out


def _has_colour(png, rgb, tol=0.08):
    img = mpimg.imread(png)[..., :3]
    return bool(np.any(np.all(np.abs(img - np.asarray(rgb)) < tol, axis=-1)))


def _hex(c):
    return [int(c[i:i + 2], 16) / 255 for i in (1, 3, 5)]


def test_views_draw_perception_in_pink_and_the_estimate_in_green(traces, tmp_path):
    t = {m: r["trace"] for m, r in traces.items()}
    p = plots.plot_views(t, tmp_path / "views.png")
    assert p.stat().st_size > 10_000
    assert _has_colour(p, _hex(plots.PINK)) and _has_colour(p, _hex(plots.GREEN))
    assert t["particles"]["cloud"] is not None and t["paper"]["cloud"] is not None
    assert t["last-seen"]["cloud"] is None


def test_error_over_time(traces, tmp_path):
    t = {m: r["trace"] for m, r in traces.items()}
    p = plots.plot_error_over_time(t, tmp_path / "error.png")
    assert p.stat().st_size > 10_000


def test_reliability_update_time_and_metric_bars_from_rows(traces, tmp_path):
    rows = [r["row"] for r in traces.values()]
    # a second particle count, for the scaling plot
    extra = dict(rows[-1], particles=16, key=rows[-1]["key"].replace("K4", "K16"),
                 timing=dict(rows[-1]["timing"], update_ms_median=4 * rows[-1]["timing"]["update_ms_median"]))
    rows.append(extra)
    assert plots.plot_reliability(rows, tmp_path / "rel.png").stat().st_size > 10_000
    assert plots.plot_update_time(rows, tmp_path / "time.png").stat().st_size > 10_000
    summary = summarize(rows)
    assert plots.plot_metrics(summary, tmp_path / "metrics.png").stat().st_size > 10_000


def test_make_figures_writes_every_figure(traces, tmp_path):
    import json
    rows = [r["row"] for r in traces.values()]
    (tmp_path / "traces").mkdir()
    for r in traces.values():
        (tmp_path / "traces" / f"{r['row']['key']}.json").write_text(json.dumps(r["trace"]))
    paths = plots.make_figures(rows, summarize(rows), tmp_path)
    names = {p.name for p in paths}
    assert names == {"views_cup_falls_behind_box.png", "error_cup_falls_behind_box.png", "reliability.png",
                     "update_time.png", "metrics.png"}
    assert all(p.stat().st_size > 0 for p in paths)


def test_method_colours():
    assert plots.method_color("particles") == plots.GREEN
    assert plots.method_color("paper") != plots.method_color("last-seen")
    assert len({plots.method_color(m) for m in ("particles-no-params", "particles-no-held",
                                                "particles-no-negative")}) == 3
