"""The interactive viewer section of ``report.html``: one large canvas (root element ``id="viewer"``)
that flips between the reference and each method, as the shaded image, V or the signed error
``V - V_ref``, at one zoom and pan (wheel, drag); hovering reads out V of the current method and of
the reference and their difference at that pixel.

Self-contained: the script (``viewer.js`` next to this module) and the CSS are inlined; each item
carries its shaded PNG as a data URI and V as zlib-compressed little-endian uint16 (``V * QMAX``
rounded, ``65535`` = background), which the page inflates with the browser's
``DecompressionStream``; the V and error layers are drawn from those arrays through the same colour
tables as the PNGs (``shading.visibility_to_rgb``, ``report.error_rgb``). About 30-80 KB per method
at 320x240. User documentation: ``docs/viewer-and-pareto.md``.
"""

from __future__ import annotations

import base64
import html
import json
import zlib
from importlib import resources

import numpy as np

#: V quantisation: q = round(V * QMAX); step 1/65534 (1.5e-5), below the 4 decimals shown
QMAX = 65534
NAN_CODE = 65535


def quantize_v(v: np.ndarray) -> np.ndarray:
    """(H,W) V -> uint16 codes (``round(clip(V,0,1) * QMAX)``, background/NaN -> ``NAN_CODE``)."""
    a = np.asarray(v, dtype=np.float64)
    q = np.rint(np.clip(np.nan_to_num(a, nan=0.0), 0.0, 1.0) * QMAX).astype(np.uint16)
    q[~np.isfinite(a)] = NAN_CODE
    return q


def dequantize_v(q: np.ndarray) -> np.ndarray:
    """The inverse of :func:`quantize_v` (what the page computes), float64 with NaN background."""
    out = q.astype(np.float64) / QMAX
    out[q == NAN_CODE] = np.nan
    return out


def encode_v(v: np.ndarray) -> str:
    """base64 of the zlib-compressed little-endian uint16 codes of V."""
    return base64.b64encode(zlib.compress(quantize_v(v).astype("<u2").tobytes(), 9)).decode("ascii")


def _luts() -> dict:
    """Colour tables of the V and error layers, identical to the PNGs' colouring."""
    from ..shading import to_srgb8, visibility_to_rgb
    from .figures import error_rgb

    t = np.linspace(0.0, 1.0, 256, dtype=np.float32)[None, :]
    lut_v = to_srgb8(visibility_to_rgb(t))[0]
    bg_v = to_srgb8(visibility_to_rgb(np.full((1, 1), np.nan, np.float32)))[0, 0]
    # error e maps to index round((e / (2 L) + 0.5) * 255); error_rgb(x * 2L - L, L) is that colour
    lut_err = error_rgb((t.astype(np.float64) - 0.5) * 2.0, 1.0)[0]
    bg_err = error_rgb(np.full((1, 1), np.nan), 1.0)[0, 0]
    return {
        "lut_v": lut_v.reshape(-1).tolist(),
        "bg_v": bg_v.tolist(),
        "lut_err": lut_err.reshape(-1).tolist(),
        "bg_err": bg_err.tolist(),
    }


def viewer_payload(items: list[dict], limit: float) -> dict:
    """The viewer's data. ``items``: the reference first, then the methods, each a dict with
    ``name``, ``v`` ((H,W) V, NaN background), ``image`` (shaded PNG bytes) and an optional
    ``caption``; ``limit`` is the error maps' symmetric colour limit."""
    from .html import data_uri

    if not items:
        raise ValueError("the viewer needs at least the reference")
    h, w = np.asarray(items[0]["v"]).shape
    out = []
    for it in items:
        if np.asarray(it["v"]).shape != (h, w):
            raise ValueError(f"viewer item {it['name']}: V shape {np.asarray(it['v']).shape} != {(h, w)}")
        out.append(
            {
                "name": str(it["name"]),
                "caption": str(it.get("caption", "")),
                "image": data_uri(it["image"]),
                "vq": encode_v(it["v"]),
            }
        )
    return {"w": int(w), "h": int(h), "limit": float(limit), "qmax": QMAX, "items": out, **_luts()}


_CSS = """
#viewer{border:1px solid #ccc;border-radius:6px;padding:8px;background:#f7f7f9;margin:8px 0}
#viewer .vbar{display:flex;flex-wrap:wrap;gap:4px;align-items:center;margin:0 0 6px}
#viewer button{font:12px system-ui,sans-serif;padding:3px 8px;border:1px solid #aab;border-radius:4px;background:#fff;cursor:pointer}
#viewer button.on{background:#246;color:#fff;border-color:#246}
#viewer button kbd{font-size:10px;color:#889;margin-right:4px} #viewer button.on kbd{color:#cde}
#viewer .sep{width:14px}
#viewer canvas{display:block;width:100%;height:min(72vh,720px);image-rendering:pixelated;cursor:crosshair;
  touch-action:none;background:#202024;border-radius:3px}
#viewer-readout{font:12.5px ui-monospace,Menlo,Consolas,monospace;min-height:1.4em;margin-top:4px;white-space:pre}
#viewer-caption{font-size:12px;color:#444}
"""


def viewer_html(payload: dict) -> str:
    """The ``<section>`` with the viewer: buttons, canvas, readout, data and inline script."""
    e = html.escape
    btns = []
    for i, it in enumerate(payload["items"]):
        key = f"<kbd>{i + 1}</kbd>" if i < 9 else ""
        btns.append(f'<button type="button" data-item="{i}" title="{e(it["caption"])}">{key}{e(it["name"])}</button>')
    layers = (("image", "s", "shaded"), ("v", "v", "V"), ("error", "e", "signed error"))
    lbtns = [f'<button type="button" data-layer="{k}"><kbd>{key}</kbd>{lbl}</button>' for k, key, lbl in layers]
    js = resources.files(__package__).joinpath("viewer.js").read_text(encoding="utf-8")
    data = json.dumps(payload, separators=(",", ":")).replace("</", "<\\/")
    return (
        f"<style>{_CSS}</style>"
        '<h2 id="viewer-title">Viewer</h2>'
        "<div class='sub'>Number keys or buttons pick the image (1 = reference), <kbd>&larr;</kbd>/<kbd>&rarr;</kbd> "
        "step, <kbd>r</kbd> flips to the reference and back; <kbd>s</kbd> shaded, <kbd>v</kbd> V, <kbd>e</kbd> signed "
        "error V &minus; V_ref (red = darker than truth, blue = brighter). Wheel zooms about the cursor, drag pans, "
        "<kbd>0</kbd> fits; the view stays put while switching. Hover for V and the error at a pixel.</div>"
        '<div id="viewer" tabindex="0">'
        f'<div class="vbar">{"".join(btns)}<span class="sep"></span>{"".join(lbtns)}'
        '<span class="sep"></span><button type="button" data-act="fit"><kbd>0</kbd>fit</button></div>'
        '<canvas aria-label="comparison viewer"></canvas>'
        '<div id="viewer-caption"></div><div id="viewer-readout">hover the image for V</div></div>'
        f'<script type="application/json" id="viewer-data">{data}</script>'
        f"<script>{js}</script>"
    )
