"""`compare` writes every file and the report names every method; `bench` and `sweep` on tiny inputs."""

import json
import os
import re

import numpy as np
import pytest

import softshadows as ss
from softshadows.bench import bench, format_table, sweep, translate_occluders
from softshadows.cli import main
from softshadows.compare import compare, parse_method_sets, resolve_methods
from softshadows.errors import SoftShadowsError

W, H = 48, 36


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    out = tmp_path_factory.mktemp("cmp")
    res = compare("spheres", "all", W, H, str(out), {"pcss": {"filter_samples": "25"}}, gt_samples=16)
    return out, res


def test_compare_writes_every_file(compared):
    out, res = compared
    methods = list(res["metrics"])
    assert "hard" in methods and "pcss" in methods and "ground-truth" not in methods
    expected = {"ground-truth.png", "ground-truth_V.png", "grid.png", "metrics.json", "report.html"}
    for m in methods:
        expected |= {f"{m}.png", f"{m}_V.png", f"{m}_error.png"}
    assert expected <= set(os.listdir(out))
    for f in expected:
        assert os.path.getsize(out / f) > 0
    from PIL import Image

    assert Image.open(out / "pcss.png").size == (W, H)
    assert Image.open(out / "pcss_V.png").size == (W, H)
    assert not res["failed"]


def test_metrics_json_and_report_name_every_method(compared):
    out, res = compared
    doc = json.loads((out / "metrics.json").read_text())
    assert set(doc["methods"]) == set(res["metrics"])
    assert doc["methods"]["pcss"]["params"]["filter_samples"] == 25  # --set reached the method
    for d in doc["methods"].values():
        assert 0.0 <= d["metrics"]["mae"] <= 1.0
        assert d["timings"]["total"] > 0
    html = (out / "report.html").read_text()
    for m in list(res["metrics"]) + ["ground-truth"]:
        assert re.search(rf">{re.escape(m)}<", html), m
    # self-contained: images are data URIs, no external references
    assert html.count("data:image/png;base64,") >= 1 + 3 * len(res["metrics"])
    assert not re.search(r"""(src|href)=["'](http|file:|/)""", html)
    assert "sortTable" in html and "numba" in html  # sortable tables, machine description


def test_first_run_timings_are_flagged(monkeypatch, tmp_path):
    # with a warm-up helper (a cold cache) the frames are timed while it compiles: the report,
    # metrics.json and the result say so; without one (a warm cache) nothing is said
    from softshadows import _warm
    from softshadows.compare import COMPILING_NOTE

    class FakeHelper:  # the main process renders everything itself
        def claim(self, name):
            return True

        def cached(self, name):
            return False

    monkeypatch.setattr(_warm, "stop_warmup", lambda helper: None)
    for helper in (FakeHelper(), None):
        monkeypatch.setattr(_warm, "start_warmup", lambda *a, h=helper, **k: h)
        out = tmp_path / str(helper is None)
        res = compare("spheres", "hard", 24, 18, str(out), gt_samples=4)
        flagged = helper is not None
        assert res["timed_while_compiling"] is flagged and "hard" in res["timings"]
        assert json.loads((out / "metrics.json").read_text())["timed_while_compiling"] is flagged
        assert (COMPILING_NOTE.split(";")[0] in (out / "report.html").read_text()) is flagged


def test_skipped_light_shape_is_noted(monkeypatch):
    from softshadows.methods import base, methods

    methods()  # load the registry, then add a rect-only method (every built-in one supports both)

    class RectOnly(base.Method):
        name = "rect-only-test"
        light_shapes = ("rect",)

    monkeypatch.setitem(base._REGISTRY, RectOnly.name, RectOnly())
    run, skipped = resolve_methods("all", "sphere")
    assert "rect-only-test" in skipped and "rect-only-test" not in run
    assert "rect" in skipped["rect-only-test"]
    assert "hard" in run and "soft-shadow-map" in run
    run, skipped = resolve_methods("all", "rect")
    assert "rect-only-test" in run and not skipped


def test_receivers_only_method_is_also_measured_over_receivers(compared):
    """The soft shadow map shades only receivers (no self-shadowing): on ``spheres`` (occluder
    spheres in self-shadow, receiver ground) its all-surface error includes the unshadowed sides of
    the spheres, the receivers-only error does not, so it is lower and over fewer pixels; other
    methods get no receivers-only figures. The JSON and the report carry both, labelled."""
    out, res = compared
    mt = res["metrics"]["soft-shadow-map"]
    rc = mt["receivers"]
    assert 0 < rc["n_pixels"] < mt["n_pixels"]
    assert rc["mae"] < mt["mae"]
    assert all("receivers" not in x for m, x in res["metrics"].items() if m != "soft-shadow-map")
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["methods"]["soft-shadow-map"]["metrics"]["receivers"]["mae"] == pytest.approx(rc["mae"])
    html = (out / "report.html").read_text()
    assert "soft-shadow-map (all surfaces)" in html and "soft-shadow-map (receivers only)" in html


def test_bad_input_is_one_line_error(tmp_path, capsys):
    with pytest.raises(SoftShadowsError, match="unknown method 'nope'"):
        resolve_methods("hard,nope", "rect")
    with pytest.raises(SoftShadowsError):
        parse_method_sets(["pcss_filter_samples=3"])
    with pytest.raises(SoftShadowsError, match="filter_samples"):
        compare("square", "pcss", 16, 12, str(tmp_path), {"pcss": {"filter_samples": "-1"}}, gt_samples=4)
    assert main(["compare", "square", "--methods", "hard,nope", "-o", str(tmp_path)]) == 2
    assert main(["compare", "square", "--size", "12by7", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all(line.startswith("softshadows: error:") for line in err)


def test_bench_ratio_to_hard_and_table():
    res = bench("square", "pcss", [32, "40x30"], repeats=2, warmup=0)
    rows = {(tuple(r["size"]), r["method"]): r for r in res["results"]}
    assert set(rows) == {((32, 32), "hard"), ((32, 32), "pcss"), ((40, 30), "hard"), ((40, 30), "pcss")}
    for (_size, m), r in rows.items():
        t = r["timings"]["total"]
        assert t["n"] == 2 and t["min"] <= t["median"] <= t["max"]
        pr = r["ratio_to_hard_paired"]  # each round's frame against hard's frame of that round
        assert pr["n"] == 2 and pr["min"] <= pr["q1"] <= pr["median"] <= pr["q3"] <= pr["max"]
        if m == "hard":
            assert r["ratio_to_hard"] == pytest.approx(1.0)
            assert pr["min"] == pr["max"] == 1.0  # paired with itself, round by round
        else:  # the two rounds' ratios lie between the extreme ratios of the rounds' totals
            h = rows[(_size, "hard")]["timings"]["total"]
            assert t["min"] / h["max"] <= pr["min"] <= pr["max"] <= t["max"] / h["min"]
        assert "shadow_map" in r["timings"]
    assert "blocker_search" in rows[((32, 32), "pcss")]["timings"]
    assert "pcss" in format_table(res)


def test_sweep_light_size(tmp_path):
    png = tmp_path / "sweep.png"
    d = sweep("square", "light-size", [0.5, 1.5], "pcss,hard", (40, 30), None, str(png), gt_samples=16, repeats=1)
    assert png.exists() and png.stat().st_size > 0
    assert d["x"] == [0.5, 1.5]
    # a bigger light gives wider penumbrae: hard shadows get worse against ground truth
    assert d["methods"]["hard"]["mae"][1] > d["methods"]["hard"]["mae"][0]


def test_sweep_geometry_edits():
    sc = ss.load_scene("square")
    up = translate_occluders(sc, 0.5)
    occ = next(m for m in up.meshes if m.role == "occluder")
    assert np.allclose(occ.vertices[:, 1], 1.5)
    assert np.allclose(next(m for m in sc.meshes if m.role == "occluder").vertices[:, 1], 1.0)  # original untouched
    with pytest.raises(SoftShadowsError):
        translate_occluders(sc, 5.0)  # above the light
    with pytest.raises(SoftShadowsError):
        sweep("square", "wobble", [1], "pcss", (16, 16))
