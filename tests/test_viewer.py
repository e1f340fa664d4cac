"""The report viewer (report/viewer.py + viewer.js): the V encoding round-trips, and in headless
Chromium the buttons, number keys, wheel zoom, hover readout, table links and the drawn pixels behave."""

import base64
import io
import os
import re
import shutil
import zlib

import numpy as np
import pytest

import softshadows as ss
from softshadows.compare import compare
from softshadows.report.viewer import QMAX, dequantize_v, encode_v, quantize_v
from softshadows.shading import to_srgb8, visibility_to_rgb

W, H = 64, 48
GT_SAMPLES = 16
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def test_v_encoding_round_trips():
    rng = np.random.default_rng(1)
    v = rng.random((7, 9)).astype(np.float32)
    v[0, :3] = np.nan
    v[1, 0], v[1, 1] = 0.0, 1.0
    q = np.frombuffer(zlib.decompress(base64.b64decode(encode_v(v))), "<u2").reshape(v.shape)
    assert np.array_equal(q, quantize_v(v))
    back = dequantize_v(q)
    assert np.array_equal(np.isnan(back), np.isnan(v))
    # rounding to the nearest code: at most half a step off
    assert np.nanmax(np.abs(back - v)) <= 0.5 / QMAX + 1e-7
    assert back[1, 0] == 0.0 and back[1, 1] == 1.0


def _chromium():
    """(executable, None) or (None, why not)."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None and os.path.exists("/usr/bin/chromium"):
        exe = "/usr/bin/chromium"
    if exe is None:
        return None, "no Chromium installed (Debian: apt-get install chromium); the viewer browser test needs it"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return None, "playwright is not installed (pip install playwright; it drives the system Chromium)"
    return exe, None


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("viewer")
    res = compare("spheres", "hard,pcss", W, H, str(out), gt_samples=GT_SAMPLES)
    assert not res["failed"]
    scene = ss.load_scene("spheres")
    # the same renders again (deterministic for a seed): the arrays the hover readout must show
    vs = {
        "ground-truth": ss.render(scene, "ground-truth", W, H, samples=GT_SAMPLES).visibility,
        "hard": ss.render(scene, "hard", W, H).visibility,
        "pcss": ss.render(scene, "pcss", W, H).visibility,
    }
    return out / "report.html", vs


@pytest.fixture(scope="module")
def page(request):
    exe, why = _chromium()
    if exe is None:
        print(f"SKIP viewer browser test: {why}")
        pytest.skip(why)
    report = request.getfixturevalue("report")  # only rendered when a browser can show it
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        pg = browser.new_page(viewport={"width": 1000, "height": 800}, device_scale_factor=1)
        errors = []
        pg.on("pageerror", lambda e: errors.append(str(e)))
        pg.goto(report[0].as_uri())
        pg.wait_for_selector("#viewer[data-ready='1']", timeout=20000)
        yield pg, errors
        browser.close()


def _state(pg):
    v = pg.locator("#viewer")
    return {k: v.get_attribute(f"data-{k}") for k in ("method", "layer", "zoom", "tx", "ty", "error")}


def _canvas_rgb(pg) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(pg.locator("#viewer canvas").screenshot())).convert("RGB")).astype(int)


def _screen_of(pg, x, y):
    """Canvas-relative CSS position of the centre of image pixel (x, y) from the viewer's own transform."""
    st = _state(pg)
    z, tx, ty = float(st["zoom"]), float(st["tx"]), float(st["ty"])
    return tx + (x + 0.5) * z, ty + (y + 0.5) * z


def _readout(pg):
    text = pg.locator("#viewer-readout").inner_text()
    m = re.search(r"\((\d+), (\d+)\)\s+(\S+) V = (\S+)\s+(\S+) V = (\S+)\s+error = (\S+)", text)
    assert m, text
    return int(m[1]), int(m[2]), m[3], float(m[4]), m[5], float(m[6]), float(m[7])


def test_switch_methods_by_button_and_key(page):
    pg, errors = page
    assert _state(pg)["method"] == "hard"  # the first method is shown first
    pg.locator("#viewer button[data-item]", has_text="pcss").click()
    assert _state(pg)["method"] == "pcss"
    pg.keyboard.press("1")
    assert _state(pg)["method"] == "ground-truth"
    pg.keyboard.press("2")
    assert _state(pg)["method"] == "hard"
    pg.keyboard.press("v")
    assert _state(pg)["layer"] == "v"
    pg.keyboard.press("s")
    assert _state(pg)["layer"] == "image"
    # the metrics table's method names link to the viewer
    pg.locator("#metrics a", has_text="pcss").click()
    pg.wait_for_function("document.getElementById('viewer').dataset.method === 'pcss'")
    assert not errors, errors


def test_wheel_zoom_keeps_view_while_switching(page):
    pg, errors = page
    pg.keyboard.press("0")
    z0 = float(_state(pg)["zoom"])
    box = pg.locator("#viewer canvas").bounding_box()
    pg.mouse.move(box["x"] + box["width"] * 0.4, box["y"] + box["height"] * 0.6)
    pg.mouse.wheel(0, -400)
    pg.wait_for_function(f"parseFloat(document.getElementById('viewer').dataset.zoom) > {z0}")
    st = _state(pg)
    assert float(st["zoom"]) > 1.5 * z0
    pg.keyboard.press("3")
    st2 = _state(pg)
    assert st2["method"] == "pcss"
    assert (st2["zoom"], st2["tx"], st2["ty"]) == (st["zoom"], st["tx"], st["ty"])
    pg.keyboard.press("0")
    assert float(_state(pg)["zoom"]) == z0
    assert not errors, errors


def test_hover_reads_v_of_method_reference_and_error(page, report):
    pg, errors = page
    _, vs = report
    ref, pc = vs["ground-truth"], vs["pcss"]
    d = np.abs(pc - ref)
    d[~np.isfinite(d)] = -1
    y, x = np.unravel_index(np.argmax(d), d.shape)  # where pcss and the truth differ most
    assert d[y, x] > 0.05
    pg.keyboard.press("3")
    pg.keyboard.press("0")
    box = pg.locator("#viewer canvas").bounding_box()
    cx, cy = _screen_of(pg, x, y)
    pg.mouse.move(box["x"] + cx, box["y"] + cy)
    rx, ry, name, v, rname, vref, err = _readout(pg)
    # tolerance: V is quantised to 1/65534 and shown with 4 decimals (5e-5), so 1e-4 covers both
    assert (rx, ry, name, rname) == (x, y, "pcss", "ground-truth")
    assert abs(v - pc[y, x]) < 1e-4
    assert abs(vref - ref[y, x]) < 1e-4
    assert abs(err - (pc[y, x] - ref[y, x])) < 1e-4
    pg.keyboard.press("2")  # switching updates the readout under a still cursor
    rx, ry, name, v, _, vref, _ = _readout(pg)
    assert name == "hard" and abs(v - vs["hard"][y, x]) < 1e-4 and abs(vref - ref[y, x]) < 1e-4
    assert not errors, errors


def test_screenshot_pixels_are_crisp_v_and_differ_between_methods(page, report):
    pg, errors = page
    _, vs = report
    pg.keyboard.press("0")
    pg.keyboard.press("v")
    shots = {}
    for key, name in (("1", "ground-truth"), ("2", "hard"), ("3", "pcss")):
        pg.keyboard.press(key)
        assert _state(pg)["method"] == name
        shots[name] = _canvas_rgb(pg)
    img = shots["pcss"]
    assert img.std() > 20  # not blank: lit floor, shadows and background
    # the whole image shows at a whole zoom factor, so each image pixel is a block of one colour,
    # exactly the V colour of the _V.png (sRGB of V). Checked at each pixel's centre and near its
    # top-left corner (0.2 pixel in): with smoothing on, the corner would blend in the neighbours.
    z = float(_state(pg)["zoom"])
    assert z >= 3 and z.is_integer()
    expect = to_srgb8(visibility_to_rgb(vs["pcss"]))
    bad, edges = 0, 0
    for y in range(1, H):
        for x in range(1, W):
            cx, cy = _screen_of(pg, x, y)
            corner = img[int(cy - 0.3 * z), int(cx - 0.3 * z)]
            bad += np.abs(img[int(cy), int(cx)] - expect[y, x]).max() > 1
            bad += np.abs(corner - expect[y, x]).max() > 1
            edges += np.abs(expect[y - 1 : y + 1, x - 1 : x + 1].astype(int) - expect[y, x]).max() > 8
    assert edges > 50  # enough pixels whose neighbours differ for blur to show
    assert bad == 0
    for a, b in (("hard", "pcss"), ("ground-truth", "hard"), ("ground-truth", "pcss")):
        assert np.abs(shots[a] - shots[b]).mean() > 0.5, (a, b)  # different shadows on screen
    pg.keyboard.press("e")
    err = _canvas_rgb(pg)
    assert np.abs(err - img).mean() > 5  # the error layer is another picture
    pg.keyboard.press("s")
    assert not errors, errors
