"""Comparison output: signed-error heat maps, the labelled grid, sweep plots, the HTML report.

* :func:`error_heatmap` (:func:`error_heatmaps`: several, on one figure) / :func:`error_rgb` /
  :func:`error_limit` — diverging ``RdBu`` maps of ``V - V_ref`` with symmetric limits (red:
  darker than truth, blue: brighter);
* :func:`grid_image` — one labelled image of every method (shaded, V, error);
* :func:`sweep_plot` — frame time and error against a swept parameter (``softshadows bench --sweep``);
* :func:`write_html` — the self-contained ``report.html``; :func:`machine_info`;
* ``report.viewer`` — its interactive viewer section (``viewer_payload``, ``viewer_html``, ``viewer.js``).
"""

from .figures import colorbar_png, error_heatmap, error_heatmaps, error_limit, error_rgb, grid_image, sweep_plot
from .html import machine_info, render_html, write_html

__all__ = [
    "colorbar_png",
    "error_heatmap",
    "error_heatmaps",
    "error_limit",
    "error_rgb",
    "grid_image",
    "machine_info",
    "render_html",
    "sweep_plot",
    "write_html",
]
