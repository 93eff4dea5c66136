"""`kinetree view` in headless Chromium: the page loads offline with no console error, draws
the mechanism, and follows the slider, the play button and a click on the plot."""

import io
import os
import pathlib
import subprocess

import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import sync_playwright

ROOT = pathlib.Path(__file__).resolve().parents[2]
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
# As root and without a GPU: no sandbox, WebGL through SwiftShader, no background traffic.
ARGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def kinetree(*args):
    binary = os.environ.get("KINETREE_BIN", str(ROOT / "target" / "debug" / "kinetree"))
    return subprocess.run([binary, *map(str, args)], check=True, capture_output=True, text=True)


def make_view(tmp, *simulate_args):
    sim = tmp / "sim"
    kinetree("simulate", *simulate_args, "-o", sim)
    kinetree("discover", sim / "tracks.npy", "-o", tmp / "model.json")
    kinetree("view", tmp / "model.json", sim / "tracks.npz", "-o", tmp / "view.html", "--title", "probe <&>")
    return tmp / "view.html"


def pixels(png):
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


@pytest.fixture(scope="module")
def browser():
    if not pathlib.Path(CHROMIUM).exists():
        pytest.fail(f"no Chromium at {CHROMIUM}: apt-get install chromium, or set CHROMIUM")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


@pytest.mark.parametrize(
    "mechanism",
    [
        ["--mechanism", "paper-arm"],
        ["--mechanism", "random", "--joints", "4", "--tree", "--seed", "3", "--dropout", "0.2"],
    ],
    ids=["paper-arm", "random-tree"],
)
def test_the_view_draws_and_follows_the_controls(browser, tmp_path, mechanism):
    page_path = make_view(tmp_path, *mechanism)
    page = browser.new_page(viewport={"width": 1200, "height": 700})
    problems, requests = [], []
    page.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: problems.append(str(e)))
    page.on("request", lambda r: requests.append(r.url))
    page.goto(page_path.as_uri())
    page.wait_for_function("window.kinetreeViewer && window.kinetreeViewer.ready", timeout=30000)
    page.wait_for_timeout(300)
    assert page.title() == "probe <&>"
    assert page.locator("#title").text_content() == "probe <&>"
    canvas = page.locator("#view3d canvas")
    first = pixels(canvas.screenshot())
    drawn = (first.sum(axis=2) < 3 * 250).sum()
    assert drawn > 300, f"the 3D view is blank ({drawn} drawn pixels)"
    n_frames = page.evaluate("window.kinetreeViewer.nFrames")
    assert n_frames > 50
    # The slider moves the mechanism.
    page.locator("#frame").fill(str(n_frames // 2))
    page.wait_for_timeout(300)
    assert page.evaluate("window.kinetreeViewer.frame") == n_frames // 2
    assert f"({n_frames // 2 + 1}/{n_frames})" in page.locator("#frame-label").text_content()
    moved = pixels(canvas.screenshot())
    changed = (np.abs(first - moved).sum(axis=2) > 30).sum()
    assert changed > 100, f"moving the slider changed {changed} pixels"
    # The plot of the joint positions is drawn, and a click on it picks a frame.
    plot = page.locator("#plot canvas")
    assert (pixels(plot.screenshot()).sum(axis=2) < 3 * 200).sum() > 500
    box = page.locator("#plot .u-over").bounding_box()
    page.mouse.click(box["x"] + 0.2 * box["width"], box["y"] + 0.5 * box["height"])
    page.wait_for_timeout(200)
    clicked = page.evaluate("window.kinetreeViewer.frame")
    assert clicked < n_frames // 3
    # Play advances the frames; pause stops them.
    page.locator("#play").click()
    page.wait_for_timeout(700)
    page.locator("#play").click()
    stopped = page.evaluate("window.kinetreeViewer.frame")
    assert not page.evaluate("window.kinetreeViewer.playing")
    page.wait_for_timeout(300)
    assert page.evaluate("window.kinetreeViewer.frame") == stopped
    assert stopped != clicked, "playing advanced the frames"
    # Orbiting (a drag on the 3D view) changes the picture too.
    before = pixels(canvas.screenshot())
    view = canvas.bounding_box()
    page.mouse.move(view["x"] + 300, view["y"] + 300)
    page.mouse.down()
    page.mouse.move(view["x"] + 420, view["y"] + 340, steps=8)
    page.mouse.up()
    page.wait_for_timeout(300)
    assert (np.abs(before - pixels(canvas.screenshot())).sum(axis=2) > 30).sum() > 100
    assert problems == [], problems
    assert all(u.startswith(("file:", "data:", "blob:")) for u in requests), requests
    page.close()
