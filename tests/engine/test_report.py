"""The HTML report (codev_engine.view.report): parsed back, and shown by a real browser."""

from __future__ import annotations

import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.view.report import markdown_html, report_html, write_report

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DI_TEXT = (EXAMPLES / "double_integrator.toml").read_text()
UNSAFE_TEXT = (
    DI_TEXT.split("[[verify.safe]]")[0]
    + "\n[[verify.unsafe]]\nlower = [-1.0, -1.0]\nupper = [1.0, 1.0]\n"
)


class Page(HTMLParser):
    """Tags counted, every URL-valued attribute and the text collected."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: dict[str, int] = {}
        self.urls: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags[tag] = self.tags.get(tag, 0) + 1
        for k, v in attrs:
            if k in ("src", "href", "xlink:href", "action", "poster", "data") and v:
                self.urls.append(v)

    def handle_data(self, data):
        self.text.append(data)


def parse(text: str) -> Page:
    page = Page()
    page.feed(text)
    return page


@pytest.fixture(scope="module")
def unsafe_report():
    problem = ce.loads_spec(UNSAFE_TEXT, path="di+unsafe.toml")
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    assert result.verdict == "unsafe"
    return problem, law, result, report_html(problem, law, result, traces=4)


def test_report_holds_the_story_and_fetches_nothing(unsafe_report):
    problem, law, result, text = unsafe_report
    page = parse(text)
    words = " ".join(page.text)
    assert text.startswith("<!DOCTYPE html>")
    assert page.tags["figure"] == 3 and page.tags["svg"] == 3  # tube, partition, inputs
    assert "UNSAFE" in words and "enters unsafe set 0" in words
    assert f"{law.num_regions}" in words and "x1" in words and "sha256" in words
    assert "[[verify.unsafe]]" in words  # the spec
    # nothing from elsewhere: URL attributes are in-page references only
    assert page.urls and all(u.startswith("#") for u in page.urls), page.urls[:5]
    assert "script" not in page.tags and "link" not in page.tags and "img" not in page.tags
    assert "@import" not in text and "url(http" not in text


def test_report_without_result_and_one_state(tmp_path):
    problem = ce.load_spec(EXAMPLES / "cruise_control.toml")
    law = ce.synthesize(problem)
    path = write_report(tmp_path / "sub" / "cc.html", problem, law, None, traces=2)
    page = parse(path.read_text())
    assert page.tags["figure"] == 2  # the partition and the inputs
    assert "not verified" in " ".join(page.text)
    assert not any(p.name.startswith(".tmp-") for p in path.parent.iterdir())


def test_markdown_subset():
    out = markdown_html("# a\n\ntext **b** `c<d>`\n\n- x\n- y\n\n| | |\n|---|---|\n| k | v |\n")
    assert "<h2>a</h2>" in out and "<b>b</b>" in out and "<code>c&lt;d&gt;</code>" in out
    assert "<ul><li>x</li><li>y</li></ul>" in out
    assert "<table><tr><td>k</td><td>v</td></tr></table>" in out


@pytest.mark.skipif(
    shutil.which("chromium") is None, reason="no chromium (apt-get install chromium)"
)
def test_report_renders_in_headless_chromium(unsafe_report, tmp_path):
    """Debian's chromium, offline, shows the page: a screenshot with the red banner and
    the figures (not a blank page)."""
    from matplotlib.image import imread

    *_, text = unsafe_report
    page = tmp_path / "r.html"
    page.write_text(text)
    shot = tmp_path / "shot.png"
    subprocess.run(
        [
            "chromium",
            "--headless=new",
            "--no-sandbox",
            "--disable-gpu",
            f"--user-data-dir={tmp_path / 'profile'}",
            "--window-size=1200,2400",
            f"--screenshot={shot}",
            page.as_uri(),
        ],
        check=True,
        capture_output=True,
        timeout=120,
    )
    image = imread(shot)[..., :3]
    assert image.shape[:2] == (2400, 1200)
    banner = image[20:60, 100:1000].reshape(-1, 3).mean(axis=0)
    assert banner[0] > 0.6 and banner[1] < 0.35  # the unsafe banner is red
    inked = np.mean(image.min(axis=2) < 0.9)
    assert inked > 0.05  # text and figures, not a blank page


def test_report_of_a_soft_output_design_shows_the_output_and_its_bound():
    """The report's figure has a y0 = C x panel with the soft bound (issue 25)."""
    text = (EXAMPLES / "mass_spring_soft.toml").read_text().replace(
        "time_horizon = 8.0", "time_horizon = 1.0")
    problem = ce.loads_spec(text)
    law = ce.synthesize(problem)
    page = report_html(problem, law, ce.verify(problem, law), traces=2)
    assert "y0 = C x" in page and "y_max (soft)" in page


def test_report_of_an_all_time_spec_ends_the_time_axes_at_the_shown_horizon():
    # time_horizon = "inf": the inputs' figure once set its x limit to inf (a ValueError)
    from codev_engine.reach.simulate import shown_horizon

    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    text = report_html(problem, law, result, traces=3)
    assert parse(text).tags["figure"] == 3
    assert np.isfinite(shown_horizon(problem)) and shown_horizon(problem) > 0


@pytest.mark.slow
@pytest.mark.parametrize("spec", sorted(p.name for p in EXAMPLES.glob("*.toml")))
def test_report_of_every_bundled_example(spec, tmp_path):
    problem = ce.load_spec(EXAMPLES / spec)
    law = ce.synthesize(problem)
    result = ce.verify(problem, law) if problem.verify is not None else None
    path = write_report(tmp_path / "r.html", problem, law, result, traces=4)
    page = parse(path.read_text())
    assert page.tags["figure"] >= 2 and "nan" not in " ".join(page.text).lower().split()
