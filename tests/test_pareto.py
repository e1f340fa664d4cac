"""`pareto`: the front holds no dominated point, the budget choice fits and is never dominated, the
cache behind `render --method auto`, a small real sweep, and Ctrl-C leaving partial results."""

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import softshadows
import softshadows as ss
from softshadows.cli import main
from softshadows.errors import SoftShadowsError
from softshadows.methods import get_method
from softshadows.pareto import (
    auto_choice,
    cache_key,
    choose,
    load_cached,
    pareto,
    pareto_mask,
    store_cached,
)

W, H = 48, 36
TINY = {  # a few settings each: the test is about the machinery, not the methods
    "ground-truth": {"samples": [1, 16]},
    "hard": {"map_size": [128, 512]},
    "pcss": {"filter_samples": [4, 16]},
}


def dominates(a, b):
    return a[0] <= b[0] and a[1] <= b[1] and (a[0] < b[0] or a[1] < b[1])


def brute_front(pts):
    return [not any(dominates(q, p) for q in pts) for p in pts]


# small integer grids make ties (equal times, equal errors, duplicates) common
coord = st.one_of(st.integers(0, 6).map(float), st.floats(0.0, 100.0, allow_nan=False))
point_sets = st.lists(st.tuples(coord, coord), min_size=0, max_size=40)


@settings(max_examples=300, deadline=None)
@given(point_sets)
def test_front_has_no_dominated_point_and_dominates_the_rest(pts):
    mask = pareto_mask([p[0] for p in pts], [p[1] for p in pts])
    assert list(mask) == brute_front(pts)
    front = [p for p, m in zip(pts, mask) if m]
    for p, m in zip(pts, mask):
        if not m:  # everything off the front is beaten by a point on it
            assert any(dominates(q, p) for q in front)


def test_front_ignores_missing_values():
    mask = pareto_mask([1.0, None, 2.0, float("nan")], [0.5, 0.0, 0.1, 0.0])
    assert list(mask) == [True, False, True, False]


@settings(max_examples=300, deadline=None)
@given(point_sets.filter(bool), st.floats(0.01, 120.0))
def test_budget_pick_fits_and_is_never_dominated(pts, budget):
    points = [{"method": "m", "params": {"i": i}, "ms": a, "mae": b} for i, (a, b) in enumerate(pts)]
    p, fits = choose(points, budget)
    q = (p["ms"], p["mae"])
    assert not any(dominates(r, q) for r in pts)
    within = [r for r in pts if r[0] <= budget]
    if within:
        assert fits and p["ms"] <= budget
        assert p["mae"] == min(r[1] for r in within)  # the least error that fits
    else:
        assert not fits and p["ms"] == min(r[0] for r in pts)  # nothing fits: the fastest


def test_budget_must_be_positive():
    pts = [{"method": "m", "params": {}, "ms": 1.0, "mae": 0.1}]
    for bad in (0, -1, float("nan"), None):
        with pytest.raises(SoftShadowsError, match="budget"):
            choose(pts, bad)


def test_sweep_settings_product_list_and_validation():
    hard = get_method("hard")
    assert hard.sweep_settings({"map_size": [64, 128], "pcf": [0, 1]}) == [
        {"map_size": 64, "pcf": 0},
        {"map_size": 64, "pcf": 1},
        {"map_size": 128, "pcf": 0},
        {"map_size": 128, "pcf": 1},
    ]
    assert hard.sweep_settings([{"map_size": "64"}, {"map_size": 64}]) == [{"map_size": 64}]  # coerced, deduped
    with pytest.raises(SoftShadowsError, match="pcf"):
        hard.sweep_settings({"pcf": [99]})
    with pytest.raises(SoftShadowsError, match="unknown parameter"):
        hard.sweep_settings({"nope": [1]})
    # every registered method's declared sweep is valid and names only its own parameters
    for name, m in ss.methods().items():
        assert m.sweep_settings(), name


def _synthetic(scene, w, h):
    pts = [
        ("hard", {"map_size": 256}, 1.0, 0.05),
        ("pcss", {"filter_samples": 16}, 5.0, 0.01),
        ("pcss", {"filter_samples": 64}, 20.0, 0.004),
        ("ground-truth", {"samples": 64}, 900.0, 0.002),
        ("hard", {"map_size": 4096}, 950.0, 0.05),  # dominated
    ]
    points = [{"method": m, "params": p, "ms": ms, "mae": e} for m, p, ms, e in pts]
    return {"complete": True, "points": points}


def test_auto_reads_the_cache_huge_budget_most_accurate_tiny_fastest(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTSHADOWS_CACHE_DIR", str(tmp_path))
    scene = ss.load_scene("square")
    store_cached(_synthetic(scene, W, H), scene, W, H)
    m, p, _, fits, _ = auto_choice(scene, W, H, 1e9, verbose=False)
    assert (m, p, fits) == ("ground-truth", {"samples": 64}, True)
    m, p, _, fits, _ = auto_choice(scene, W, H, 1e-6, verbose=False)
    assert (m, p, fits) == ("hard", {"map_size": 256}, False)
    m, p, _, fits, _ = auto_choice(scene, W, H, 21.0, verbose=False)
    assert (m, p, fits) == ("pcss", {"filter_samples": 64}, True)
    # the cache is keyed by project version, scene content, light and size
    assert load_cached(scene, W, H) is not None
    assert load_cached(scene, W + 1, H) is None
    assert load_cached(ss.load_scene("square", light="sphere"), W, H) is None
    moved = scene.with_camera(ss.Camera(scene.camera.eye + 0.1, scene.camera.target))
    assert cache_key(moved, W, H)["scene"] != cache_key(scene, W, H)["scene"]
    assert load_cached(moved, W, H) is None
    monkeypatch.setattr(softshadows, "__version__", "999.0")
    assert load_cached(scene, W, H) is None


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("pareto")
    cache = tmp_path_factory.mktemp("cache")
    mp = pytest.MonkeyPatch()
    mp.setenv("SOFTSHADOWS_CACHE_DIR", str(cache))
    doc = pareto(
        "square", "ground-truth,hard,pcss", W, H, str(out), 16, repeats=2, sweeps=TINY, budget_ms=1e9, cache=True
    )
    yield out, cache, doc
    mp.undo()


def test_real_sweep_writes_files_and_a_consistent_front(swept):
    out, _, _ = swept
    for f in ("pareto.json", "pareto.png", "pareto.md", "pareto.html"):
        assert (out / f).stat().st_size > 0, f
    js = json.loads((out / "pareto.json").read_text())
    assert js["complete"] and len(js["points"]) == 6
    pts = [(p["ms"], p["mae"]) for p in js["points"]]
    for p in js["points"]:
        assert set(p) >= {"method", "params", "ms", "mae", "on_front"}
        assert p["ms"] > 0 and 0 <= p["mae"] <= 1 and len(p["times_ms"]) == 2
    assert [p["on_front"] for p in js["points"]] == brute_front(pts)
    by = {(p["method"], json.dumps(p["params"], sort_keys=True)): p for p in js["points"]}
    gt1, gt16 = by[("ground-truth", '{"samples": 1}')], by[("ground-truth", '{"samples": 16}')]
    # the reference has other samples (its own seed): 16 samples are not an exact copy, yet much
    # closer than 1 sample (a hard shadow from one jittered point); MC error falls ~ 1/sqrt(N)
    assert 0 < gt16["mae"] < 0.5 * gt1["mae"]
    # PCSS's soft penumbra is closer to the truth than the hard shadow map on this scene
    assert max(by[("pcss", k)]["mae"] for k in ('{"filter_samples": 16}',)) < min(
        p["mae"] for p in js["points"] if p["method"] == "hard"
    )
    # the huge budget picks the least error overall
    assert js["budget"]["fits"] and js["budget"]["mae"] == min(p["mae"] for p in js["points"])
    html = (out / "pareto.html").read_text()
    assert "data:image/png;base64," in html and "ground-truth" in html
    # the page's viewer holds the reference and each front setting, linked from the table
    data = json.loads(html.split('<script type="application/json" id="viewer-data">', 1)[1].split("</script>", 1)[0])
    front = sorted((p for p in js["points"] if p["on_front"]), key=lambda p: p["ms"])
    labels = [f"{p['method']} " + ", ".join(f"{k}={v}" for k, v in p["params"].items()) for p in front]
    assert [it["name"] for it in data["items"]] == ["ground-truth", *labels]
    assert html.count('href="#viewer?m=') == len(front)


def test_render_auto_end_to_end(swept, tmp_path, monkeypatch, capsys):
    _, cache, doc = swept
    monkeypatch.setenv("SOFTSHADOWS_CACHE_DIR", str(cache))
    pts = doc["points"]
    best = min(pts, key=lambda p: p["mae"])
    fastest = min(pts, key=lambda p: p["ms"])
    png = tmp_path / "a.png"
    assert (
        main(["render", "square", "--method", "auto", "--budget-ms", "1e9", "--size", f"{W}x{H}", "-o", str(png)]) == 0
    )
    out = capsys.readouterr().out
    assert f"auto (1e+09 ms budget): {best['method']} " in out and png.stat().st_size > 0
    for k, v in best["params"].items():
        assert f"{k}={v}" in out
    assert (
        main(["render", "square", "--method", "auto", "--budget-ms", "1e-6", "--size", f"{W}x{H}", "-o", str(png)]) == 0
    )
    out = capsys.readouterr().out
    assert f"auto (1e-06 ms budget): {fastest['method']} " in out and "nothing fits" in out


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["render", "square", "--method", "hard", "--budget-ms", "5", "-o", str(tmp_path / "x.png")]) == 2
    assert main(["render", "square", "--method", "auto", "-o", str(tmp_path / "x.png")]) == 2
    assert main(["render", "square", "--method", "auto", "--budget-ms", "5", "--set", "pcf=1"]) == 2
    assert main(["pareto", "square", "--repeats", "0", "-o", str(tmp_path)]) == 2
    assert main(["pareto", "square", "--budget-ms", "-3", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5 and all(line.startswith("softshadows: error:") for line in err)


def test_ctrl_c_leaves_partial_results(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = softshadows.render

    def interrupted(*a, **k):
        calls["n"] += 1
        if calls["n"] == 7:  # the reference, 4 warm-up frames, 1 timed frame, then Ctrl-C
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(softshadows, "render", interrupted)
    with pytest.raises(KeyboardInterrupt):
        pareto("square", "hard", W, H, str(tmp_path), 4, repeats=2, sweeps={"hard": {"map_size": [64, 128, 256, 512]}})
    js = json.loads((tmp_path / "pareto.json").read_text())
    assert not js["complete"]
    assert all(p["mae"] is not None for p in js["points"])  # every warm-up frame's error was written
    timed = [p for p in js["points"] if p["ms"] is not None]
    assert len(timed) == 1 and timed[0]["on_front"]
    assert (tmp_path / "pareto.png").exists() and "partial" in (tmp_path / "pareto.html").read_text()
    assert not [f for f in tmp_path.iterdir() if ".tmp" in f.name]  # no temporary file left behind
    assert math.isfinite(timed[0]["ms"])
    assert np.isfinite([p["mae"] for p in js["points"]]).all()


def test_a_failing_setting_is_reported_and_the_sweep_goes_on(tmp_path, monkeypatch):
    real = softshadows.render

    def flaky(scene, method, *a, **k):
        if method == "hard" and k.get("map_size") == 128:
            raise MemoryError("simulated")
        return real(scene, method, *a, **k)

    monkeypatch.setattr(softshadows, "render", flaky)
    doc = pareto("square", "hard", W, H, str(tmp_path), 4, repeats=1, sweeps={"hard": {"map_size": [64, 128, 256]}})
    bad = [p for p in doc["points"] if "failed" in p]
    assert len(bad) == 1 and bad[0]["params"] == {"map_size": 128} and "MemoryError" in bad[0]["failed"]
    assert bad[0]["ms"] is None and not bad[0]["on_front"]
    good = [p for p in doc["points"] if "failed" not in p]
    assert len(good) == 2 and all(p["ms"] > 0 and p["mae"] is not None for p in good) and doc["complete"]
