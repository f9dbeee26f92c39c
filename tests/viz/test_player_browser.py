"""The episode player in headless Chromium: `drivee2e view` on a tiny results
folder (2 scenarios), then the page loads without console errors and its
controls (play, step, scrub, episode picker, infraction markers) work.

Needs Debian's ``chromium`` (``/usr/bin/chromium``) and Playwright for Python
(``pip install playwright``; its own browser download is NOT used)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from drivee2e_jax.cli import main

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--no-first-run"]


@pytest.fixture(scope="module")
def player(tmp_path_factory):
    """A results folder of the expert on the tiny suite's 2 train scenarios, and its player."""
    from drivee2e_jax.scenario.schema import write_suite
    from tests.helpers.tiny_suite import build_tiny_suite

    root = tmp_path_factory.mktemp("viewer")
    suite = write_suite(build_tiny_suite(), root / "tiny")
    run = root / "run"
    assert main(["bench", "--suite", str(suite), "--split", "train", "--out", str(run), "--no-progress",
                 "--policy", "expert"]) == 0
    out = root / "player.html"
    assert main(["view", str(run), "--out", str(out)]) == 0
    return run, out


@pytest.fixture(scope="module")
def browser():
    playwright = pytest.importorskip("playwright.sync_api", reason="Playwright for Python is not installed "
                                     "(pip install playwright; the system chromium is used)")
    if not Path(CHROMIUM).exists():
        pytest.skip(f"no chromium at {CHROMIUM} (apt-get install -y chromium)")
    with playwright.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def test_player_controls_in_headless_chromium(player, browser, tmp_path):
    _, html = player
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    problems = []
    page.on("console", lambda m: problems.append(f"console.{m.type}: {m.text}") if m.type in ("error", "warning") else None)
    page.on("pageerror", lambda e: problems.append(f"pageerror: {e}"))
    page.on("request", lambda r: problems.append(f"request: {r.url}") if not r.url.startswith(("file:", "data:")) else None)
    page.goto(html.as_uri())
    page.wait_for_function("window.player !== undefined")
    frame = lambda: int(page.get_attribute("body", "data-frame"))  # noqa: E731
    n = page.evaluate("window.player.episodes[0].n")
    assert n > 10 and frame() == 0
    assert page.locator("#scenario option").count() == 2

    page.click("#play")
    page.wait_for_function("Number(document.body.dataset.frame) >= 3", timeout=10_000)
    page.click("#play")  # pause
    paused = frame()
    page.wait_for_timeout(300)
    assert frame() == paused and page.inner_text("#play").strip().endswith("play")

    page.click("#fwd")
    assert frame() == paused + 1
    page.click("#back")
    page.click("#back")
    assert frame() == paused - 1
    page.keyboard.press("ArrowRight")
    assert frame() == paused

    page.locator("#scrub").fill(str(n - 1))
    assert frame() == n - 1
    assert f"frame {n}/{n}" in page.inner_text("#frame-label")

    # An infraction marker on the timeline jumps to its frame.
    markers = page.evaluate("window.player.state.markers")
    assert markers, "the tiny expert run has infraction events"
    box = page.locator("#timeline").bounding_box()
    page.mouse.click(box["x"] + markers[0]["x"], box["y"] + markers[0]["y"])
    assert frame() == markers[0]["frame"]

    page.select_option("#scenario", "1")
    assert frame() == 0 and page.evaluate("window.player.state.ep") == 1
    assert "s_left" in page.inner_text("#info") or "s_left" in page.inner_text("#scenario")

    # Sensor panes drew something other than their background.
    page.locator("#scrub").fill("20")
    page.wait_for_timeout(200)
    lit = page.evaluate("""id => { const c = document.getElementById(id), d = c.getContext('2d')
        .getImageData(0, 0, c.width, c.height).data; let k = 0;
        for (let i = 0; i < d.length; i += 4) k += (d[i] + d[i + 1] + d[i + 2]) > 0; return k; }""", "bev")
    assert lit > 1000
    shot = tmp_path / "player.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 20_000
    assert not problems, problems


def test_view_cli_errors_are_one_line(player, tmp_path, capsys):
    run, html = player
    cases = [
        (["view", str(tmp_path / "nope"), "--out", str(tmp_path / "a.html")], "no such results folder"),
        (["view", str(run), "--out", str(html)], "exists; use --force"),
        (["view", str(run), "--out", str(tmp_path / "a.html"), "--scenario", "zz"], "--scenario zz: not in this run"),
        (["view", str(run), "--out", str(tmp_path / "a.html"), "--policy", "zz"], "--policy zz"),
    ]
    for argv, needle in cases:
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0] and "Traceback" not in err[0], err
    assert not (tmp_path / "a.html").exists()
