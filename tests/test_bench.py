"""The benchmark command: its figures are there, finite and consistent (no assertion on speed)."""
import json
import math

import pytest

from experiments.bench import bench_one, bench_scene
from experiments.cli import main


@pytest.mark.parametrize("workers", [0, 2])
def test_bench_one_reports_consistent_figures(workers):
    r = bench_one(4, 2, workers, updates=3, warmup=1)
    assert (r["particles"], r["objects"], r["workers"], r["steps_per_update"]) == (4, 2, workers, 19)
    for name in ("update_ms_median", "update_ms_p95", "bare_step_ms_median", "main_ms_median",
                 "slowest_shard_ms_median", "peak_memory_mb"):
        assert math.isfinite(r[name]) and r[name] > 0, name
    assert r["ratio"] == pytest.approx(r["update_ms_median"] / r["bare_step_ms_median"])
    assert r["updates_per_s"] == pytest.approx(1e3 / r["update_ms_median"])
    assert r["update_ms_p95"] >= r["update_ms_median"]
    assert math.isfinite(r["exchange_ms_median"]) and math.isfinite(r["worker_overhead_us_per_particle"])
    assert len(bench_scene(2).objects) == 3  # the table and two boxes


def test_bench_command_prints_json(capsys):
    assert main(["bench", "--particles", "2", "--objects", "2", "--updates", "2", "--workers", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["workers"] == 0 and len(out["results"]) == 1 and out["results"][0]["particles"] == 2
    assert main(["bench", "--particles", "2", "--objects", "2", "--updates", "2", "--workers", "0",
                 "--breakdown"]) == 0
    assert "over us/particle" in capsys.readouterr().out


def test_bench_times_a_configuration_file(tmp_path, capsys):
    (tmp_path / "c.yaml").write_text("noise: {position_std: 0.02}\nreasoner: {horizon: 0.1}\n")
    assert main(["bench", "--particles", "2", "--objects", "2", "--updates", "2", "--workers", "0", "--json",
                 "--config", str(tmp_path / "c.yaml")]) == 0
    r = json.loads(capsys.readouterr().out)["results"][0]
    assert r["particles"] == 2 and r["steps_per_update"] == 24  # the file's horizon: 0.1 s of 1/240 s steps
