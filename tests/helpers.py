"""Shared builders for the tests: small scenes and synthetic frames."""
from __future__ import annotations

import json
import math
import shutil
import tempfile

import numpy as np

from estimator.observations import Detection, Frame
from physics.scene import scene_from_dict

TABLE_TOP = 0.626  # pybullet_data table/table.urdf, at the origin


def table_scene(*objects, camera=None, floor=True):
    data = {"name": "test", "floor": floor, "objects": [
        {"id": "table", "static": True, "urdf": "pybullet_data://table/table.urdf",
         "pose": {"position": [0, 0, 0]}}, *objects]}
    if camera is not None:
        data["camera"] = camera
    return scene_from_dict(data)


def det(position, orientation=(0, 0, 0, 1)):
    return Detection(np.asarray(position, float), None if orientation is None else np.asarray(orientation, float))


def frames(times, objects_at):
    """Frames at ``times``; ``objects_at(t)`` returns {id: position or (position, orientation)}."""
    out = []
    for t in times:
        objs = {}
        for oid, v in objects_at(t).items():
            if isinstance(v, tuple):
                objs[oid] = det(v[0], v[1])
            else:
                objs[oid] = det(v)
        out.append(Frame(float(t), objs))
    return out


def write_jsonl(path, rows):
    with open(path, "w") as fh:
        for r in rows:
            fh.write((r if isinstance(r, str) else json.dumps(r)) + "\n")


# -- property-based tests of the readers: arbitrary JSON-like values, reproducible (derandomized) -------

def json_values():
    """A hypothesis strategy of arbitrary JSON-like values (NaN and infinities included)."""
    from hypothesis import strategies as st
    leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
                     st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8))
    return st.recursive(leaf, lambda c: st.one_of(st.lists(c, max_size=5),
                                                  st.dictionaries(st.text(max_size=8), c, max_size=5)),
                        max_leaves=20)


def fuzz_settings(n: int = 300):
    """Hypothesis settings for the readers' property tests: ``n`` examples, the same on every run."""
    from hypothesis import HealthCheck, settings
    return settings(max_examples=n, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))


def headless_chromium():
    """A headless chromium driven by selenium, or None when chromium or its driver is absent."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if chromium is None or driver is None:
        return None
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1280,800",
                f"--user-data-dir={tempfile.mkdtemp(prefix='chromium-')}"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(driver), options=opts)


def gauss3(d, s):
    """Isotropic 3-D Gaussian density at distance d (m) from its mean, std s (m), by hand."""
    return (2 * math.pi * s * s) ** -1.5 * math.exp(-d * d / (2 * s * s))
