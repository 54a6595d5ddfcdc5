"""The report in a real browser: headless Chromium renders the page at
1280 px; it loads without a console message or an error, shows the summary, needs no
horizontal scrolling, and every figure is a decoded data-URI image drawn at its size.

Chromium is the system package (``.ci/run`` installs it); where it is absent the test is
skipped, saying so. The page is loaded from a copy with a probe script added at the top of its
head: it records any error, and on ``load`` writes each image's natural and drawn size and the
page's scroll width into an attribute of ``<body>``, which ``--dump-dom`` then prints.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from report.conftest import ReportBuild

WIDTH, HEIGHT = 1280, 2000
BROWSER = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(
    BROWSER is None,
    reason="Chromium is not on PATH (the system package: apt-get install chromium; .ci/run "
    "installs it): the report's browser test needs it",
)

PROBE = """<script>
window.__errors = [];
window.addEventListener("error", function (e) {
  window.__errors.push(String(e.message || (e.target && e.target.src || e.type)).slice(0, 200));
}, true);
window.addEventListener("load", function () {
  var root = document.documentElement;
  var out = {errors: window.__errors, scrollWidth: root.scrollWidth, innerWidth: innerWidth,
             clientWidth: root.clientWidth,
             summary: (document.getElementById("summary") || {}).innerText || "",
             summaryTop: document.getElementById("summary") ?
                         document.getElementById("summary").getBoundingClientRect().top : -1,
             images: []};
  for (var i = 0; i < document.images.length; i++) {
    var img = document.images[i], r = img.getBoundingClientRect();
    out.images.push({alt: img.alt, dataUri: img.src.indexOf("data:image/png;base64,") === 0,
                     complete: img.complete, naturalWidth: img.naturalWidth,
                     naturalHeight: img.naturalHeight, width: r.width, height: r.height,
                     left: r.left, right: r.right, box: img.parentElement.clientWidth,
                     visibility: getComputedStyle(img).visibility,
                     display: getComputedStyle(img).display});
  }
  document.body.setAttribute("data-probe", JSON.stringify(out));
});
</script>"""


def _chromium(tmp: Path, url: str, *args: str) -> subprocess.CompletedProcess[str]:
    cmd = [
        BROWSER,
        "--headless",
        "--disable-gpu",
        "--no-sandbox",
        f"--window-size={WIDTH},{HEIGHT}",
        "--enable-logging=stderr",
        "--v=0",
        "--no-first-run",
        f"--user-data-dir={tmp / 'profile'}",
        "--virtual-time-budget=10000",
        *args,
        url,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


class _Body(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.probe: str | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "body":
            self.probe = dict(attrs).get("data-probe")


@pytest.fixture(scope="module")
def probed(report_build: ReportBuild, tmp_path_factory: pytest.TempPathFactory) -> dict:
    tmp = tmp_path_factory.mktemp("chromium")
    page = report_build.path.read_text(encoding="utf-8")
    head = page.index("<head>") + len("<head>")
    copy = tmp / "report.html"
    copy.write_text(page[:head] + PROBE + page[head:], encoding="utf-8")
    run = _chromium(tmp, copy.as_uri(), "--dump-dom")
    assert run.returncode == 0, run.stderr[-2000:]
    body = _Body()
    body.feed(run.stdout)
    assert body.probe, "the probe did not run: " + run.stderr[-2000:]
    return {"probe": json.loads(body.probe), "stderr": run.stderr, "tmp": tmp, "copy": copy}


def test_the_page_loads_without_console_messages_or_errors(probed: dict) -> None:
    console = [ln for ln in probed["stderr"].splitlines() if ":CONSOLE" in ln or "Uncaught" in ln]
    assert not console, console  # the page has no script: any message is a fault
    assert probed["probe"]["errors"] == []


def test_the_summary_is_on_the_first_screen(probed: dict, report_build: ReportBuild) -> None:
    p = probed["probe"]
    verdict = "PASSED" if report_build.verification.passed else "FAILED"
    assert f"Summary: {verdict}" in p["summary"] and "What to do next:" in p["summary"]
    assert 0 <= p["summaryTop"] < HEIGHT / 2


def test_readable_at_1280_px_without_horizontal_scrolling(probed: dict) -> None:
    p = probed["probe"]
    assert p["innerWidth"] == WIDTH
    # the content fits the viewport less its vertical scroll bar
    assert p["scrollWidth"] <= p["clientWidth"] <= p["innerWidth"], p


def test_every_figure_is_embedded_decoded_and_drawn_at_its_size(
    probed: dict, report_build: ReportBuild
) -> None:
    images = probed["probe"]["images"]
    page = report_build.path.read_text(encoding="utf-8")
    assert len(images) == page.count("<img ") > 10
    for im in images:
        name = im["alt"]
        assert im["dataUri"] and im["complete"], name
        assert im["naturalWidth"] > 200 and im["naturalHeight"] > 150, name  # decoded
        assert im["visibility"] == "visible" and im["display"] != "none", name
        # drawn at its natural width, or scaled down to the text column, never cut off
        expected = min(im["naturalWidth"], im["box"])
        assert abs(im["width"] - expected) <= 1.0, (name, im)
        ratio = im["naturalHeight"] / im["naturalWidth"]
        assert abs(im["height"] - im["width"] * ratio) <= 1.5, (name, im)
        assert im["left"] >= 0 and im["right"] <= WIDTH, (name, im)
        assert im["width"] >= 0.5 * min(im["naturalWidth"], 1000), name  # readable, not a thumb


def test_the_screenshot_shows_the_page(probed: dict) -> None:
    shot = probed["tmp"] / "shot.png"
    run = _chromium(probed["tmp"], probed["copy"].as_uri(), f"--screenshot={shot}")
    assert run.returncode == 0 and shot.is_file(), run.stderr[-2000:]
    rgb = imread(shot)[..., :3]
    assert rgb.shape[:2] == (HEIGHT, WIDTH)
    assert float(rgb.std()) > 0.05  # not blank
    # the summary box (its pass or fail background) is drawn on the first screen
    colours = {(0.933, 1.0, 0.933), (1.0, 0.933, 0.933)}  # #efe, #fee
    hits = sum(int(np.all(np.abs(rgb - np.array(c)) < 0.01, axis=-1).sum()) for c in colours)
    assert hits > 20_000, hits
