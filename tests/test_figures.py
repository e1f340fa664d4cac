"""The report's error heat maps: colours where the error is known, and several maps drawn on one
figure give the PNGs of one figure each."""

import io

import numpy as np
from PIL import Image

from softshadows.report import error_heatmap, error_heatmaps


def test_heatmap_colours_follow_the_sign_of_the_error():
    # V - V_ref = +limit (left half): blue, brighter than truth; -limit (right half): red; NaN (no
    # surface, top rows): the light-grey background. The map is 64x48, drawn at 5x (320x240 px)
    # below a 0.3 in title band, so image row r, column c is PNG pixel (30 + 5 r, 5 c)
    err = np.full((48, 64), -0.2)
    err[:, :32] = 0.2
    err[:8] = np.nan
    png = Image.open(io.BytesIO(error_heatmap(err, 0.2, title="m: V - V_ref"))).convert("RGB")
    px = np.asarray(png).astype(int)
    blue, red, grey = px[30 + 5 * 24, 5 * 16], px[30 + 5 * 24, 5 * 48], px[30 + 5 * 4, 5 * 32]
    # RdBu's ends (err / (2 limit) + 0.5 = 1 and 0), within a unit of rounding
    assert np.all(np.abs(blue - (5, 48, 97)) <= 1) and np.all(np.abs(red - (103, 0, 31)) <= 1)
    assert np.all(np.abs(grey - 209) <= 1)  # BACKGROUND = 0.82 grey


def test_heatmaps_on_one_figure_are_the_separate_figures_bit_for_bit():
    # error_heatmaps redraws one figure with each map and title (a new figure where the size or
    # the title band changes): every PNG must be the one a figure of its own gives
    rng = np.random.default_rng(5)
    maps = [rng.uniform(-0.3, 0.3, (48, 64)) for _ in range(3)] + [rng.uniform(-0.3, 0.3, (40, 30))]
    maps += [rng.uniform(-0.3, 0.3, (40, 30))]
    maps[1][:10] = np.nan
    titles = ["a: V - V_ref", "b: V - V_ref", None, "d: V - V_ref", "e: V - V_ref"]
    together = error_heatmaps(maps, 0.25, titles=titles)
    apart = [error_heatmap(m, 0.25, title=t) for m, t in zip(maps, titles, strict=True)]
    assert together == apart
    assert len(set(together)) == len(maps)
