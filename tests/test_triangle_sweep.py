"""The triangle-throughput sweep (`softshadows bench icosphere --sweep triangles`, issue 15): its scene,
its table and the llvmpipe peer column (or its n/a and reason where GL is unavailable)."""

from __future__ import annotations

import numpy as np
import pytest

from softshadows.bench import sweep, triangles_table
from softshadows.errors import SoftShadowsError
from softshadows.peer import unavailable
from softshadows.scene.builtin import icosphere


def test_icosphere_scene_counts_and_shape():
    for level in (0, 2):
        sc = icosphere(level)
        fl = sc.flat
        # trimesh's icosphere: 20 * 4^level faces, 10 * 4^level + 2 vertices, plus the ground quad
        assert len(fl.faces) == 20 * 4**level + 2
        assert int(fl.occluder.sum()) == 20 * 4**level
        ball = sc.meshes[1].vertices
        np.testing.assert_allclose(np.linalg.norm(ball - [0.0, 1.0, 0.0], axis=1), 0.6, rtol=1e-12)
    assert icosphere(1, "sphere").light.shape == "sphere"
    with pytest.raises(SoftShadowsError, match="level"):
        icosphere(11)


def test_icosphere_triangles_sweep_table(tmp_path):
    png = tmp_path / "tri.png"
    d = sweep("icosphere", "triangles", [0, 1], "pcss", (48, 36), None, str(png), gt_samples=4, repeats=1)
    # hard is added (the x-hard columns and the peer need it); x is every triangle of the scene
    assert list(d["methods"]) == ["hard", "pcss"]
    assert d["x"] == [20 * 4**0 + 2, 20 * 4**1 + 2]
    for m in d["methods"].values():
        assert all(np.isfinite(t) and t > 0 for t in m["time_ms"])
    assert all(np.isfinite(t) and t > 0 for t in d["reference_time_ms"])
    peers = d["peers"]
    assert list(peers) == ["hard", "pcss"]  # the GL frames of the swept methods
    table = triangles_table(d)
    lines = table.splitlines()
    assert lines[0] == "| triangles | hard | pcss | ground-truth (4 spp) | llvmpipe `hard` | llvmpipe `pcss` |"
    row = lines[3].split("|")[1:-1]
    assert row[0].strip() == "82"
    hard, pcss = d["methods"]["hard"]["time_ms"][1], d["methods"]["pcss"]["time_ms"][1]
    assert row[1].strip() == f"{hard:.0f}"
    assert row[2].strip() == f"{pcss:.0f} ({pcss / hard:.2f}x)"
    why = unavailable()
    for k, (m, peer) in enumerate(peers.items()):
        cell = row[4 + k].strip()
        if why is None and peer["reason"] is None:
            # GL available: llvmpipe rendered both levels; its V agrees with ours on all but a fraction of a
            # percent of the pixels (hard: exactly, but where a float32 depth comparison flips; pcss: within
            # AGREEMENT_TOL, but where a float32 tap comparison flips)
            assert all(np.isfinite(t) and t > 0 for t in peer["time_ms"])
            assert max(peer["disagree"]) < 0.005 and max(peer["cover"]) < 0.005
            ours = d["methods"][m]["time_ms"][1]
            assert cell == f"{peer['time_ms'][1]:.0f} ({peer['time_ms'][1] / ours:.2f}x)"
        else:
            # no GL: the column says n/a and the table says why, in one line
            assert all(np.isnan(peer["time_ms"]))
            assert cell == "n/a"
            assert f"llvmpipe `{m}`: n/a: {peer['reason']}" in lines and "\n" not in peer["reason"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_icosphere_sweep_peer_says_why_it_cannot_render_the_parameters():
    # GLHard has no PCF: with pcf set, the peer's column is n/a and the table says why
    d = sweep("icosphere", "triangles", [0], "hard", (32, 24), {"hard": {"pcf": 1}}, None, gt_samples=1, repeats=1)
    lines = triangles_table(d).splitlines()
    assert lines[2].split("|")[-2].strip() == "n/a"
    assert lines[-1] == "llvmpipe `hard`: n/a: GLHard renders hard without PCF (pcf 0)"


def test_icosphere_sweep_bad_input():
    with pytest.raises(SoftShadowsError, match="triangles"):
        sweep("icosphere", "light-size", [1.0], "pcss", (16, 16))
    with pytest.raises(SoftShadowsError, match="levels"):
        sweep("icosphere", "triangles", [1.5], "pcss", (16, 16))


def test_icosphere_sweep_without_gl_says_why(monkeypatch):
    import softshadows.peer as peer_mod

    monkeypatch.setattr(peer_mod, "unavailable", lambda: "moderngl is not installed (pip install -e '.[peer]')")
    d = sweep("icosphere", "triangles", [0], "hard", (32, 24), None, None, gt_samples=1, repeats=1)
    lines = triangles_table(d).splitlines()
    assert lines[2].split("|")[-2].strip() == "n/a"
    assert lines[-1] == "llvmpipe `hard`: n/a: moderngl is not installed (pip install -e '.[peer]')"
    assert np.isfinite(d["methods"]["hard"]["time_ms"][0])
