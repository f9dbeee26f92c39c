"""The episode player in headless Chromium: `drivee2e view` on a tiny results
folder (2 scenarios), then the page loads without console errors, loads each
episode's file only when it is opened, and its controls (play, step, scrub,
episode picker, infraction markers) work; on a page of hand-built traces
(``tests/viz/fakes.py``, no simulation) the index filters and sorts, two
policies play side by side, and infraction labels never overlap.

Needs Debian's ``chromium`` (``/usr/bin/chromium``) and Playwright for Python
(``pip install playwright``; its own browser download is NOT used)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from drivee2e_jax.cli import main
from drivee2e_jax.viz.player import write_player
from tests.helpers.fake_traces import fake_trace

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
    out = root / "view" / "player.html"
    assert main(["view", str(run), "--out", str(out), "--no-progress"]) == 0
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
    scripts = []
    page.on("request", lambda r: scripts.append(r.url.rsplit("/", 2)[-2:]) if r.url.endswith(".js") else None)
    page.goto(html.as_uri())
    page.wait_for_function("document.body.dataset.loaded !== undefined")
    frame = lambda: int(page.get_attribute("body", "data-frame"))  # noqa: E731
    n = page.evaluate("window.player.state.cur.n")
    assert n > 10 and frame() == 0
    assert page.locator("#scenario option").count() == 2 and page.locator("#index tbody tr").count() == 2
    # Only the opened episode (and its map) came in, each from its own file beside the page.
    assert sorted(page.evaluate("window.player.loaded()")) == ["episode:e00000", "map:m0"]
    assert scripts == [["episodes", "e00000.js"], ["maps", "m0.js"]]

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
    page.wait_for_function("document.body.dataset.loaded === 'expert|s_left'")
    assert frame() == 0 and page.evaluate("window.player.state.pos") == 1
    assert "episode:e00001" in page.evaluate("window.player.loaded()") and ["episodes", "e00001.js"] in scripts

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
        (["view", str(run), "--out", str(tmp_path / "a.html"), "--chunk-size", "0"], "--chunk-size 0"),
        (["view", str(run), "--out", str(html.parent)], "is a folder"),
        (["view", str(run), "--out", str(tmp_path / "x" / "..")], "expected an .html file path"),
    ]
    for argv, needle in cases:
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0] and "Traceback" not in err[0], err
    assert not (tmp_path / "a.html").exists()


# --------------------------------------------------------------------------
# Index, comparison and labels on hand-built traces
# --------------------------------------------------------------------------

NEAR = [{"type": "collisions_vehicle", "t": 0.5, "x": -16.0, "y": -1.75},  # three events within 1 m
        {"type": "red_light", "t": 0.6, "x": -16.0, "y": -1.75},
        {"type": "route_dev", "t": 0.7, "x": -15.5, "y": -1.5}]
#: (scenario, policy, status, DS, behaviour, events) of the synthetic page, in index order.
EPISODES = [("s0", "expert", "Perfect", 100.0, "STR", []), ("s0", "stop", "Failed - TickRuntime", 4.0, "STR", []),
            ("s1", "expert", "Failed - Collision", 30.0, "LFT", NEAR),
            ("s1", "stop", "Failed - TickRuntime", 5.0, "LFT", []),
            ("s2", "expert", "Perfect", 90.0, "RT", [{"type": "red_light", "t": 1.0, "x": -10.0, "y": -1.75}])]


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    out = tmp_path_factory.mktemp("synthetic") / "p.html"
    traces = (fake_trace(sid, f"m{sid}", events, policy=pol, status=st, ds=ds, behavior=beh)
              for sid, pol, st, ds, beh, events in EPISODES)
    return write_player(traces, out, single_file=False)


def _open(browser, html, problems):
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    page.on("console", lambda m: problems.append(f"console.{m.type}: {m.text}") if m.type in ("error", "warning") else None)
    page.on("pageerror", lambda e: problems.append(f"pageerror: {e}"))
    page.goto(html.as_uri())
    page.wait_for_function("document.body.dataset.loaded !== undefined")
    return page


def _column(page, i):
    return [c.strip() for c in page.locator(f"#index tbody tr td:nth-child({i})").all_inner_texts()]


def test_index_filters_and_sorts(synthetic, browser):
    problems = []
    page = _open(browser, synthetic, problems)
    assert page.inner_text("#count") == "5 of 5 episodes"
    page.select_option("#f-policy", "stop")
    assert _column(page, 1) == ["stop", "stop"]
    page.select_option("#f-policy", "")
    page.select_option("#f-infraction", "*")
    assert _column(page, 2) == ["s1", "s2"] and "5 of" not in page.inner_text("#count")
    page.select_option("#f-infraction", "collisions_vehicle")
    assert _column(page, 2) == ["s1"] and "collisions_vehicle" in _column(page, 9)[0]  # after DS, DS all, DS at-fault, RC, behaviour
    page.select_option("#f-infraction", "-")
    assert _column(page, 2) == ["s0", "s0", "s1"]
    page.select_option("#f-infraction", "")
    page.select_option("#f-status", "Perfect")
    assert _column(page, 2) == ["s0", "s2"]
    page.select_option("#f-status", "")
    page.select_option("#f-behavior", "LFT")
    assert _column(page, 1) == ["expert", "stop"]
    page.select_option("#f-behavior", "")
    page.fill("#f-ds", "30")
    assert _column(page, 4) == ["4.0", "30.0", "5.0"]
    page.fill("#f-ds", "")
    page.click("#index th[data-key=ds]")
    assert _column(page, 4) == ["4.0", "5.0", "30.0", "90.0", "100.0"]
    page.click("#index th[data-key=ds]")
    assert _column(page, 4) == ["100.0", "90.0", "30.0", "5.0", "4.0"]
    page.click("#index th[data-key=infractions]")
    assert _column(page, 2)[-2:] == ["s2", "s1"]  # 1 then 3 infractions, ties in index order first
    # A row opens its episode (loaded from its file on demand).
    page.locator("#index tbody tr", has_text="s2").click()
    page.wait_for_function("document.body.dataset.loaded === 'expert|s2'")
    assert "episode:e00004" in page.evaluate("window.player.loaded()")
    assert page.locator("#index tbody tr.current").inner_text().startswith("expert")
    assert not problems, problems


def _lit(page, canvas_id):
    return page.evaluate("""id => { const c = document.getElementById(id), d = c.getContext('2d')
        .getImageData(0, 0, c.width, c.height).data; let k = 0;
        for (let i = 0; i < d.length; i += 4) k += (d[i] + d[i + 1] + d[i + 2]) > 60; return k; }""", canvas_id)


def test_two_policies_side_by_side_share_the_time_slider(synthetic, browser):
    problems = []
    page = _open(browser, synthetic, problems)
    assert page.locator("#compare option").all_inner_texts() == ["none", "stop · DS 4.0"]
    assert "split" not in (page.get_attribute("#scene-wrap", "class") or "")
    page.select_option("#compare", "1")
    page.wait_for_function("document.body.dataset.compared === 'stop|s0'")
    assert "split" in page.get_attribute("#scene-wrap", "class")
    page.locator("#scrub").fill("12")
    state = page.evaluate("({f: window.player.state.frame, a: window.player.state.cur.policy, "
                          "b: window.player.state.cmp.policy})")
    assert state == {"f": 12, "a": "expert", "b": "stop"}
    assert _lit(page, "scene2") > 1000 and _lit(page, "scene") > 1000
    # Opening another scenario keeps comparing with the same policy there.
    page.locator("#index tbody tr", has_text="s1").first.click()
    page.wait_for_function("document.body.dataset.loaded === 'expert|s1' && document.body.dataset.compared === 'stop|s1'")
    assert page.evaluate("window.player.state.frame") == 0
    page.select_option("#compare", "-1")
    assert "split" not in page.get_attribute("#scene-wrap", "class") and page.evaluate("window.player.state.cmp") is None
    assert not problems, problems


def test_infraction_labels_do_not_overlap(synthetic, browser):
    problems = []
    page = _open(browser, synthetic, problems)
    page.select_option("#scenario", "2")  # s1 expert: three events within 1 m of each other
    page.wait_for_function("document.body.dataset.loaded === 'expert|s1'")
    page.locator("#scrub").fill("20")
    labels = page.evaluate("window.player.state.labels")
    assert sorted(lb["text"] for lb in labels) == ["collisions_vehicle", "red_light", "route_dev"]

    def overlap(a, b):
        return a["x"] < b["x"] + b["w"] and b["x"] < a["x"] + a["w"] and a["y"] < b["y"] + b["h"] and b["y"] < a["y"] + a["h"]

    hud = {"x": 6, "y": 6, "w": 250, "h": 56}
    assert not any(overlap(a, b) for i, a in enumerate(labels) for b in labels[i + 1:])
    assert not any(overlap(a, hud) for a in labels)
    assert not problems, problems


def test_a_missing_episode_file_is_a_message_not_a_crash(synthetic, browser, tmp_path):
    """The page names the file it could not load (the folder was not kept beside it)."""
    import shutil

    page_copy = tmp_path / "p.html"
    shutil.copy(synthetic, page_copy)
    shutil.copytree(synthetic.parent / "p_files", tmp_path / "p_files")
    (tmp_path / "p_files" / "episodes" / "e00001.js").unlink()
    problems = []
    page = _open(browser, page_copy, problems)
    page.select_option("#scenario", "1")
    page.wait_for_function("document.getElementById('info').textContent.includes('could not load')")
    assert "e00001.js" in page.inner_text("#info") and page.evaluate("window.player.state.cur.policy") == "expert"
    assert all("ERR_FILE_NOT_FOUND" in p or "Failed to load" in p for p in problems), problems
