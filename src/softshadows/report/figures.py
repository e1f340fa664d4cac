"""Figures: signed-error heat maps with a colorbar, the labelled comparison grid, sweep plots.

Colours of the error maps (``V - V_ref``): a diverging map (matplotlib ``RdBu``) with symmetric
limits ``[-L, L]``: **red = darker than truth** (V < V_ref, too much shadow), **blue = brighter**
(V > V_ref, too little shadow), white = exact; background (no surface) is light grey.
"""

from __future__ import annotations

import io

import numpy as np

from ..io import write_bytes

CMAP = "RdBu"
BACKGROUND = (0.82, 0.82, 0.82)


def _mpl():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def error_limit(errors, percentile: float = 99.5, floor: float = 0.05) -> float:
    """A symmetric colour limit shared by several error maps: the ``percentile`` of |dV| over all
    of them, rounded up to a multiple of 0.05, at least ``floor``, at most 1."""
    vals = [np.abs(e[np.isfinite(e)]) for e in errors if e is not None and np.isfinite(e).any()]
    if not vals:
        return 1.0
    q = float(np.percentile(np.concatenate(vals), percentile))
    return float(min(1.0, max(floor, np.ceil(q / 0.05 - 1e-9) * 0.05)))


def _cmap():
    plt = _mpl()
    return plt.get_cmap(CMAP).with_extremes(bad=BACKGROUND)


def error_rgb(err: np.ndarray, limit: float) -> np.ndarray:
    """(H,W,3) uint8 colour image of a signed error map (no colorbar)."""
    cm = _cmap()
    x = np.ma.masked_invalid(np.clip(err / (2 * limit) + 0.5, 0.0, 1.0))
    return (np.asarray(cm(x))[..., :3] * 255 + 0.5).astype(np.uint8)


def _png_of(fig, dpi) -> bytes:
    """The figure as PNG bytes (the figure stays open: :func:`error_heatmaps` draws it again)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _fig_png(fig, dpi) -> bytes:
    """The figure as PNG bytes, then closed."""
    data = _png_of(fig, dpi)
    _mpl().close(fig)
    return data


#: dots per inch of the error heat maps: one figure pixel per map pixel (tiny maps upscaled)
_HEATMAP_DPI = 100


def error_heatmap(err: np.ndarray, limit: float, path=None, title: str | None = None) -> bytes:
    """PNG bytes (and file at ``path``) of a signed-error map at its native resolution with a
    colorbar labelled 'V - V_ref  (red: darker than truth, blue: brighter)'."""
    return error_heatmaps([err], limit, [path], [title])[0]


def error_heatmaps(errs, limit: float, paths=None, titles=None) -> list[bytes]:
    """:func:`error_heatmap` of each map in ``errs`` (with its path and title), drawn on one figure
    per image size: the maps, the titles and nothing else change from one to the next (a new
    figure for each cost about as much as drawing it). The same PNG bytes as one call each."""
    plt = _mpl()
    n = len(errs)
    paths = list(paths) if paths is not None else [None] * n
    titles = list(titles) if titles is not None else [None] * n
    out = []
    fig = key = None
    for err, path, title in zip(errs, paths, titles, strict=True):
        if fig is None or (err.shape, bool(title)) != key:  # (the figure's size depends on both)
            if fig is not None:
                plt.close(fig)
            fig, ax, im = _heatmap_figure(err, limit, title)
            key = (err.shape, bool(title))
        else:
            im.set_data(np.ma.masked_invalid(err))
            if title:
                ax.set_title(title, fontsize=9)
        data = _png_of(fig, _HEATMAP_DPI)
        if path is not None:
            write_bytes(path, data)
        out.append(data)
    if fig is not None:
        plt.close(fig)
    return out


def _heatmap_figure(err: np.ndarray, limit: float, title: str | None):
    """The figure of :func:`error_heatmaps` for maps of ``err``'s size: (figure, image axes, image)."""
    plt = _mpl()
    H, W = err.shape
    dpi = _HEATMAP_DPI
    scale = max(1.0, 320.0 / W)  # tiny images are upscaled (nearest) so the bar stays readable
    img_w, img_h = W * scale / dpi, H * scale / dpi
    bar_w = 1.25
    top = 0.3 if title else 0.08
    fig = plt.figure(figsize=(img_w + bar_w, img_h + top + 0.08))
    fw, fh = fig.get_size_inches()
    ax = fig.add_axes([0, 0.08 / fh, img_w / fw, img_h / fh])
    im = ax.imshow(np.ma.masked_invalid(err), cmap=_cmap(), vmin=-limit, vmax=limit, interpolation="nearest")
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=9)
    cax = fig.add_axes([(img_w + 0.12) / fw, 0.12 / fh, 0.14 / fw, (img_h - 0.08) / fh])
    cb = fig.colorbar(im, cax=cax)
    cb.ax.tick_params(labelsize=7)
    cb.set_label("V - V_ref\nred: darker than truth\nblue: brighter", fontsize=7)
    return fig, ax, im


def colorbar_png(limit: float, width_in: float = 5.0) -> bytes:
    """A horizontal colorbar legend for error maps drawn with :func:`error_rgb` at ``limit``."""
    plt = _mpl()
    import matplotlib as mpl

    fig = plt.figure(figsize=(width_in, 0.95))
    ax = fig.add_axes([0.03, 0.38, 0.94, 0.25])
    cb = mpl.colorbar.ColorbarBase(ax, cmap=_cmap(), norm=mpl.colors.Normalize(-limit, limit), orientation="horizontal")
    cb.ax.tick_params(labelsize=7)
    ax.set_title("V - V_ref:  red = darker than truth,  blue = brighter than truth", fontsize=8)
    return _fig_png(fig, 100)


def grid_image(rows: list[dict], limit: float, path=None, title: str | None = None) -> bytes:
    """A labelled grid: one row per entry ``{"label": str, "caption": str, "image": (H,W,3) uint8,
    "v": (H,W,3) uint8, "error": (H,W) float or None}``; columns shaded image | V | error map,
    one shared error colorbar. Returns PNG bytes (and writes ``path``)."""
    plt = _mpl()
    n = len(rows)
    H, W = rows[0]["image"].shape[:2]
    col_w = 3.0
    row_h = col_w * H / W + 0.45
    fig, axes = plt.subplots(n, 3, figsize=(3 * col_w + 0.9, n * row_h + (0.5 if title else 0.15)), squeeze=False)
    im = None
    for i, r in enumerate(rows):
        for j, key in enumerate(("image", "v", "error")):
            ax = axes[i, j]
            ax.set_xticks([])
            ax.set_yticks([])
            for s in ax.spines.values():
                s.set_visible(False)
            if i == 0:
                ax.set_title(("shaded image", "visibility V", "signed error V - V_ref")[j], fontsize=10)
            if key == "error":
                if r.get("error") is None:
                    ax.text(
                        0.5,
                        0.5,
                        "reference",
                        ha="center",
                        va="center",
                        fontsize=10,
                        color="0.4",
                        transform=ax.transAxes,
                    )
                    continue
                im = ax.imshow(
                    np.ma.masked_invalid(r["error"]), cmap=_cmap(), vmin=-limit, vmax=limit, interpolation="nearest"
                )
            else:
                ax.imshow(r[key], interpolation="nearest")
        axes[i, 0].set_ylabel(r["label"], fontsize=10, fontweight="bold")
        if r.get("caption"):
            axes[i, 0].set_xlabel(r["caption"], fontsize=8, loc="left")
            axes[i, 2].set_xlabel(r.get("error_caption", ""), fontsize=8, loc="left")
    top = 1.0
    if title:
        fig.suptitle(title, fontsize=11)
        top = 1.0 - 0.4 / fig.get_size_inches()[1]  # the column titles stay below it
    fig.tight_layout(rect=(0, 0, 0.92, top))
    if im is not None:
        cax = fig.add_axes([0.93, 0.25, 0.015, 0.5])
        cb = fig.colorbar(im, cax=cax)
        cb.set_label("V - V_ref (red: darker, blue: brighter than truth)", fontsize=8)
        cb.ax.tick_params(labelsize=7)
    data = _fig_png(fig, 100)
    if path is not None:
        write_bytes(path, data)
    return data


def sweep_plot(data: dict, path=None, error_key: str = "ssm_error") -> bytes:
    """Two panels against the swept parameter: frame time (ms, median) and error vs ground truth."""
    plt = _mpl()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    x = data["x"]
    for m, d in data["methods"].items():
        t = np.array(d["time_ms"], float)
        (ln,) = a1.plot(x, t, "o-", label=m)
        if d.get("time_min_ms") is not None:
            a1.fill_between(x, d["time_min_ms"], d["time_max_ms"], alpha=0.15, color=ln.get_color())
        a2.plot(x, np.array(d[error_key], float), "o-", label=m, color=ln.get_color())
    ref = data.get("reference_time_ms")
    if ref:
        a1.plot(x, ref, "s:", color="0.4", label=f"ground truth ({data['gt_samples']} spp)")
    for peer, style in zip((data.get("peers") or {}).values(), ("k--", "k-.", "k:"), strict=False):
        if np.isfinite(np.array(peer.get("time_ms") or [np.nan], float)).any():
            a1.plot(x, peer["time_ms"], style, label=peer.get("label", "peer"))
    a1.set_xlabel(data["x_label"])
    a2.set_xlabel(data["x_label"])
    a1.set_ylabel("frame time (ms, median; band: min-max)")
    a2.set_ylabel(
        {"ssm_error": "error: mean |dV| over umbra+penumbra", "mae": "mean |V - V_ref|"}.get(error_key, error_key)
    )
    for ax in (a1, a2):
        ax.grid(alpha=0.3)
        if data.get("log_x"):
            ax.set_xscale("log")
    a1.set_yscale("log")
    a1.legend(fontsize=8)
    fig.suptitle(
        f"{data['scene']}: {data['kind']} sweep ({data['size'][0]}x{data['size'][1]}, "
        f"ground truth {data['gt_samples']} samples)",
        fontsize=10,
    )
    fig.tight_layout()
    out = _fig_png(fig, 110)
    if path is not None:
        write_bytes(path, out)
    return out
