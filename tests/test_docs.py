"""The documentation: the Sphinx site builds with warnings as errors, the command reference is the
parser's, the tutorial runs as written (every command, its printed output compared with the page's),
the built site opens in a headless chromium (index, a reference page, a search with results), and no
commit hash appears in the README, the changelog or docs/."""
import functools
import http.server
import os
import re
import shutil
import socketserver
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from helpers import headless_chromium

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
TUTORIAL = DOCS / "tutorial.md"

# a commit hash: 7 to 40 hex digits with at least one letter and one digit, standing alone (not part of
# a word, a float's mantissa before its exponent, or a longer number)
HASH = re.compile(r"(?<![\w.])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w.+-])")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built once for the module: (output folder, completed process)."""
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    pytest.importorskip("furo")
    out = tmp_path_factory.mktemp("html")
    doctrees = tmp_path_factory.mktemp("doctrees")
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "-d", str(doctrees), str(DOCS), str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    return out, proc


def test_the_documentation_builds_with_warnings_as_errors(site):
    out, proc = site
    assert proc.returncode == 0, f"sphinx-build failed:\n{proc.stdout}\n{proc.stderr}"
    for page in ("index", "tutorial", "reference/formats", "reference/commands", "reference/api",
                 "concepts/likelihood", "results/index", "results/summary", "changelog"):
        assert (out / f"{page}.html").is_file(), page
    api = (out / "reference" / "api.html").read_text()
    for name in ("SceneEstimator", "EstimatorConfig", "load_scene", "Belief", "ObservationReader",
                 "BagFrameReader", "WorldGroup"):
        assert f'id="{name}' in api or f'.{name}"' in api, name


def test_the_command_reference_is_generated_from_the_parser(site):
    out, proc = site
    assert proc.returncode == 0
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        from cli_reference import subcommands
    finally:
        sys.path.remove(str(DOCS / "_ext"))
    html = (out / "reference" / "commands.html").read_text()
    from experiments.cli import build_parser

    subs = subcommands(build_parser())
    assert {"run", "config", "demo", "simulate", "evaluate", "track", "search"} <= set(subs)
    for name, (_, parser) in subs.items():
        assert f'id="command-{name}"' in html, name
        for action in parser._actions:
            for option in action.option_strings:
                if option.startswith("--") and action.help != "==SUPPRESS==":
                    assert option in html, (name, option)


def _tutorial_blocks():
    """The fenced blocks of the tutorial, in order: (kind, argument, body)."""
    text = TUTORIAL.read_text()
    return [(m.group(1), m.group(2).strip(), m.group(3))
            for m in re.finditer(r"^```(\{literalinclude\}|\w+)([^\n]*)\n(.*?)^```", text, re.M | re.S)]


def _skeleton(text: str) -> list[str]:
    """Lines with every number replaced by #: the words must match exactly, the figures only in form."""
    return [re.sub(r"-?\d+(\.\d+)?", "#", line.rstrip()) for line in text.strip().splitlines()]


def test_the_tutorial_runs_as_written(tmp_path):
    blocks = _tutorial_blocks()
    for kind, arg, _ in blocks:  # every file it shows is there
        if kind == "{literalinclude}":
            assert (DOCS / arg).is_file(), arg
    commands = [(i, body) for i, (kind, _, body) in enumerate(blocks) if kind == "bash"]
    assert len(commands) >= 4
    work = tmp_path / "tutorial"
    script = ["set -euo pipefail"]
    for i, body in commands:
        script.append(f"echo '@@block {i}'")
        script.append(body.replace("/tmp/tutorial", str(work)))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    bindir = Path(sys.executable).parent  # the scene-estimator of this Python
    env["PATH"] = os.pathsep.join([str(bindir), env.get("PATH", "")])
    if shutil.which("scene-estimator", path=env["PATH"]) is None:
        shim = tmp_path / "bin"
        shim.mkdir()
        (shim / "scene-estimator").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m experiments.cli "$@"\n')
        (shim / "scene-estimator").chmod(0o755)
        env["PATH"] = os.pathsep.join([str(shim), env["PATH"]])
    proc = subprocess.run(["bash", "-c", "\n".join(script)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=240)
    assert proc.returncode == 0, f"the tutorial's commands failed:\n{proc.stdout}\n{proc.stderr}"
    outputs = {int(m.group(1)): m.group(2) for m in
               re.finditer(r"^@@block (\d+)\n(.*?)(?=^@@block |\Z)", proc.stdout, re.M | re.S)}
    assert (work / "estimates.jsonl").is_file() and (work / "timeline.json").is_file()
    checked = 0
    for i, (kind, _, body) in enumerate(blocks):  # an output block shows what the command before it printed
        if kind != "text":
            continue
        previous = max(j for j, _ in commands if j < i)
        assert _skeleton(outputs[previous])[-len(_skeleton(body)):] == _skeleton(body), (
            f"the tutorial shows\n{body}\nbut the command printed\n{outputs[previous]}")
        checked += 1
    assert checked >= 2


def test_no_commit_hashes_in_the_documentation():
    assert HASH.search("as measured at commit 7b07bd2 and at 4abbaeb") is not None
    assert HASH.search("1.5e-05 and 0.000000000001e-05, 12345678 and deadbeef") is None
    files = subprocess.run(["git", "ls-files", "docs", "README.md", "CHANGELOG.md"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    files += [str(p.relative_to(ROOT)) for p in DOCS.rglob("*.md") if "_build" not in p.parts]
    found = {}
    for name in sorted(set(files)):
        path = ROOT / name
        if path.suffix in (".png", ".jpg", ".npz") or not path.is_file():
            continue
        hits = HASH.findall(path.read_text(errors="replace"))
        if hits:
            found[name] = hits[:5]
    assert not found, f"commit hashes in the documentation (history belongs in git log and CHANGELOG.md): {found}"


def test_the_readme_is_short_and_keeps_the_two_set_up_commands():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 260
    assert "python3 -m pip install -e . && scene-estimator demo" in readme
    assert 'python3 -m pip install -e ".[test]" && python3 -m pytest -q tests' in readme
    ci = (ROOT / ".ci" / "run").read_text()
    assert 'python3 -m pip install -q -e ".[test]"' in ci and "python3 -m pytest -q" in ci
    for link in re.findall(r"\]\(((?:docs/|CHANGELOG)[^)#]+)\)", readme):
        assert (ROOT / link).exists(), link


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def test_the_built_site_opens_in_a_headless_browser(site):
    out, proc = site
    assert proc.returncode == 0
    pytest.importorskip("selenium")
    browser = headless_chromium()
    if browser is None:
        pytest.skip("chromium and chromedriver are not installed (apt-get install chromium chromium-driver): "
                    "the built site was not opened in a browser")
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    handler = functools.partial(_Quiet, directory=str(out))
    server = socketserver.TCPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}"
    try:
        browser.get(f"{base}/index.html")
        assert "scene-estimator" in browser.title
        links = {a.get_attribute("href") for a in browser.find_elements(By.CSS_SELECTOR, "a.reference.internal")}
        assert any(href and href.endswith("tutorial.html") for href in links)

        browser.get(f"{base}/reference/commands.html")
        headings = [h.text for h in browser.find_elements(By.CSS_SELECTOR, "h2")]
        assert any(h.startswith("scene-estimator run") for h in headings), headings

        browser.get(f"{base}/search.html?q=particle")
        WebDriverWait(browser, 30).until(
            lambda b: len(b.find_elements(By.CSS_SELECTOR, "#search-results ul.search li")) > 0)
        results = browser.find_elements(By.CSS_SELECTOR, "#search-results ul.search li")
        assert len(results) >= 3
        severe = [entry for entry in browser.get_log("browser")
                  if entry["level"] == "SEVERE" and "favicon.ico" not in entry["message"]]
        assert not severe, severe
    finally:
        browser.quit()
        server.shutdown()
        server.server_close()
