"""The HTML report in a real browser: a small `compare` report opened in headless Chromium.

`report.html` is the main job's output, so this checks that a browser renders it: every image
decodes (naturalWidth > 0), every table of `report.md` is a table in the page, and a screenshot
is saved as a CI artifact (``out/browser/report.png`` under the repository, an ignored folder;
``AGENT_ENVS_ARTIFACTS`` moves it).

How the page is inspected: a copy of `report.html` beside it gets a few lines of JavaScript
that, on the window's load event, write what the browser itself reports (each image's
``complete`` and ``naturalWidth``, the number of ``<table>`` elements) into a ``<pre>``; Chromium's
``--dump-dom`` prints the DOM after loading, and the test reads that ``<pre>``. One plain
Chromium call, no WebDriver or DevTools-protocol client and no extra Python dependency; the
report itself is opened unmodified for the screenshot.

Needs Chromium (Debian: ``apt-get install chromium``). Without it the test is skipped with a
message, unless ``AGENT_ENVS_REQUIRE_BROWSER=1`` (set by `.ci/run`, which installs it): then it
fails, so CI cannot pass without having run it.
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
HEADLESS_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
CHECK_SCRIPT = """<script>
window.addEventListener("load", function () {
  var images = Array.prototype.map.call(document.images, function (im) {
    return {alt: im.alt.slice(0, 80), complete: im.complete, width: im.naturalWidth};
  });
  var pre = document.createElement("pre");
  pre.id = "browser-check";
  pre.textContent = JSON.stringify(
    {images: images, tables: document.querySelectorAll("table").length});
  document.body.appendChild(pre);
});
</script>"""


def find_browser() -> str | None:
    named = os.environ.get("AGENT_ENVS_BROWSER")
    if named:
        return named
    return next((path for name in BROWSERS if (path := shutil.which(name))), None)


def run_browser(browser: str, profile: Path, *args: str) -> subprocess.CompletedProcess:
    command = [browser, *HEADLESS_FLAGS, f"--user-data-dir={profile}", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=180, check=False)


@pytest.fixture(scope="module")
def browser() -> str:
    found = find_browser()
    if found is None:
        message = (
            "no Chromium found (looked for " + ", ".join(BROWSERS) + "; set AGENT_ENVS_BROWSER "
            "or install it, e.g. apt-get install chromium): the report's browser test is skipped"
        )
        if os.environ.get("AGENT_ENVS_REQUIRE_BROWSER") == "1":
            pytest.fail(message.replace("is skipped", "is required here"))
        pytest.skip(message)
    return found


@pytest.fixture(scope="module")
def small_report(tmp_path_factory) -> Path:
    """A smoke-preset compare (PPO at half the smoke budget, 2 test episodes, no optimum)."""
    from agent_envs.training.commands import cli

    out = tmp_path_factory.mktemp("compare-browser")
    argv = [
        "compare",
        "--preset",
        "smoke",
        "--timesteps-scale",
        "0.5",
        "--test-episodes",
        "2",
        "--optimum",
        "",
        "--no-progress-bar",
        "--out",
        str(out),
    ]
    assert cli.main(argv) == 0
    report = out / "report" / "report.html"
    assert report.is_file()
    return report


def test_report_renders_in_chromium(browser, small_report, tmp_path):
    markdown = (small_report.parent / "report.md").read_text()
    expected_images = len(re.findall(r"!\[", markdown))
    expected_tables = len(re.findall(r"^\|[-| :]+\|$", markdown, flags=re.M))
    assert expected_images > 0 and expected_tables > 0

    probe = small_report.with_name("browser_check.html")
    probe.write_text(small_report.read_text().replace("</body>", CHECK_SCRIPT + "</body>"))
    done = run_browser(
        browser, tmp_path / "profile", "--virtual-time-budget=10000", "--dump-dom", probe.as_uri()
    )
    found = re.search(r'<pre id="browser-check">(.*?)</pre>', done.stdout, flags=re.S)
    assert found, f"Chromium printed no check (exit {done.returncode}): {done.stderr[-2000:]}"
    check = json.loads(html.unescape(found.group(1)))

    images = check["images"]
    assert len(images) == expected_images, images
    broken = [im["alt"] for im in images if not im["complete"] or im["width"] <= 0]
    assert not broken, f"images that did not load: {broken}"
    assert check["tables"] == expected_tables

    artifacts = Path(os.environ.get("AGENT_ENVS_ARTIFACTS", REPO / "out" / "browser"))
    artifacts.mkdir(parents=True, exist_ok=True)
    screenshot = artifacts / "report.png"
    screenshot.unlink(missing_ok=True)
    run_browser(
        browser,
        tmp_path / "profile-shot",
        "--hide-scrollbars",
        "--window-size=1280,4000",
        f"--screenshot={screenshot}",
        small_report.as_uri(),
    )
    assert screenshot.is_file() and screenshot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
