"""A self-contained ``report.html``: every image is embedded as a base64 data URI, the tables sort
on a click of their header (a few lines of inline JavaScript), no external file or network use."""

from __future__ import annotations

import base64
import contextlib
import datetime as _dt
import html
import math
import os
import platform
import sys

from ..metrics import METRIC_HELP


def machine_info() -> dict:
    """CPU model, core counts, Numba threads, OS and library versions."""
    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info = {"cpu": cpu or platform.machine(), "logical_cores": os.cpu_count()}
    with contextlib.suppress(AttributeError):
        info["usable_cores"] = len(os.sched_getaffinity(0))
    from importlib import metadata

    vers = {"python": sys.version.split()[0]}
    for dist in ("numpy", "numba", "embreex", "trimesh", "matplotlib", "flip-evaluator"):
        try:
            vers[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            vers[dist] = "not installed"
    try:
        import numba

        info["numba_threads"] = int(numba.get_num_threads())
    except Exception:
        pass
    try:
        from .. import __version__

        vers["softshadows"] = __version__
    except Exception:
        pass
    info["os"] = f"{platform.system()} {platform.release()}"
    info["versions"] = vers
    return info


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _e(x) -> str:
    return html.escape(str(x))


def _num(v, digits=4) -> tuple[str, str]:
    """(display text, sort key) of a value."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "&ndash;", ""
    if isinstance(v, bool):
        return str(v), str(int(v))
    if isinstance(v, int):
        return f"{v:,}", str(v)
    if isinstance(v, float):
        if v != 0 and (abs(v) < 10 ** (-digits) or abs(v) >= 1e6):
            return f"{v:.{digits - 1}e}", repr(v)
        return f"{v:.{digits}f}", repr(v)
    return _e(v), _e(v)


def _ms(v) -> tuple[str, str]:
    """Milliseconds with one decimal (sort key: full precision)."""
    if v is None or not math.isfinite(v):
        return "&ndash;", ""
    return f"{v:.1f}", repr(float(v))


def _table(tid: str, header: list[tuple[str, str]], rows: list[list]) -> str:
    """A sortable table. header: (label, tooltip); rows: cells as (text, key) or raw values."""
    h = "".join(
        f'<th title="{_e(t)}" onclick="sortTable(\'{tid}\',{i})">{_e(lbl)}<span class="arr"></span></th>'
        for i, (lbl, t) in enumerate(header)
    )
    body = []
    for r in rows:
        cells = []
        for c in r:
            text, key = c if isinstance(c, tuple) else _num(c)
            cells.append(f'<td data-v="{key}">{text}</td>')
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f'<table class="sortable" id="{tid}"><thead><tr>{h}</tr></thead><tbody>{"".join(body)}</tbody></table>'


def _kv(d: dict) -> str:
    if not d:
        return "<em>(none)</em>"
    rows = []
    for k, v in d.items():
        if isinstance(v, dict):
            v = ", ".join(f"{a}={b}" for a, b in v.items())
        elif isinstance(v, float):
            v = f"{v:.6g}"
        elif isinstance(v, (list, tuple)):
            v = ", ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in v)
        rows.append(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>")
    return '<table class="kv">' + "".join(rows) + "</table>"


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px;color:#222;max-width:1500px}
h1{font-size:22px;margin:0 0 4px} h2{font-size:17px;margin:28px 0 8px;border-bottom:1px solid #ddd;padding-bottom:3px}
h3{font-size:14px;margin:6px 0}
.sub{color:#555;font-size:13px} .note{background:#fff7e0;border-left:4px solid #e0a800;padding:6px 10px;margin:6px 0;font-size:13px}
.fail{background:#fde8e8;border-left-color:#c00}
table.sortable{border-collapse:collapse;font-size:12.5px;margin:6px 0}
table.sortable th,table.sortable td{border:1px solid #ccc;padding:3px 7px;text-align:right;white-space:nowrap}
table.sortable th{background:#f0f2f5;cursor:pointer;user-select:none}
table.sortable th:hover{background:#e2e6ec}
table.sortable td:first-child,table.sortable th:first-child{text-align:left;font-weight:600}
table.sortable tr:nth-child(even) td{background:#fafafa}
.arr{color:#888;font-size:10px;margin-left:3px}
table.kv{border-collapse:collapse;font-size:12px} table.kv th{text-align:left;padding:1px 8px 1px 0;color:#444;font-weight:600;vertical-align:top}
table.kv td{padding:1px 4px;font-family:ui-monospace,Menlo,Consolas,monospace}
.cards{display:flex;flex-wrap:wrap;gap:14px}
.card{border:1px solid #ddd;border-radius:6px;padding:8px 10px;background:#fff}
.card img{display:block;image-rendering:pixelated;height:200px;width:auto}
.imgs{display:flex;gap:8px;align-items:flex-start;flex-wrap:wrap}
.imgs figure{margin:0} figcaption{font-size:11px;color:#555;text-align:center}
.grid img{max-width:100%;border:1px solid #ddd}
.meta{display:flex;gap:40px;flex-wrap:wrap}
details{margin:4px 0;font-size:12px} summary{cursor:pointer;color:#246}
code{background:#f3f3f3;padding:1px 4px;border-radius:3px}
"""

_JS = """
function sortTable(id,col){
  var t=document.getElementById(id),tb=t.tBodies[0],rows=Array.prototype.slice.call(tb.rows);
  var asc=t.getAttribute('data-col')==String(col)?t.getAttribute('data-dir')!='asc':true;
  rows.sort(function(a,b){
    var x=a.cells[col].getAttribute('data-v'),y=b.cells[col].getAttribute('data-v');
    var fx=parseFloat(x),fy=parseFloat(y),nx=x===''||isNaN(fx),ny=y===''||isNaN(fy);
    if(nx&&ny) return (x<y?-1:x>y?1:0)*(asc?1:-1); if(nx) return 1; if(ny) return -1;
    return asc?fx-fy:fy-fx;});
  rows.forEach(function(r){tb.appendChild(r);});
  t.setAttribute('data-col',col);t.setAttribute('data-dir',asc?'asc':'desc');
  var ths=t.tHead.rows[0].cells;
  for(var i=0;i<ths.length;i++){ths[i].lastChild.textContent=i==col?(asc?'\\u25B2':'\\u25BC'):'';}
}
"""

METRIC_COLS = ["mae", "rmse", "max", "bias", "ssm_error", "mae_umbra", "mae_penumbra", "mae_lit", "flip"]


def render_html(ctx: dict) -> str:
    """The report page from the context ``compare`` assembles (see ``softshadows.compare``)."""
    sc = ctx["scene"]
    ref = ctx["reference"]
    methods = ctx["methods"]
    parts = [
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{_e(ctx['title'])}</title>",
        f"<style>{_CSS}</style><script>{_JS}</script></head><body>",
    ]
    parts.append(f"<h1>{_e(ctx['title'])}</h1>")
    parts.append(
        f"<div class='sub'>{_e(ctx.get('created', _dt.datetime.now().isoformat(timespec='seconds')))}"
        f" &middot; {sc['size'][0]}x{sc['size'][1]} pixels &middot; reference: <b>{_e(ref['name'])}</b>"
        f" ({_e(ref['params'].get('samples', '?'))} light samples per pixel)"
        + (f" &middot; <code>{_e(ctx['command'])}</code>" if ctx.get("command") else "")
        + "</div>"
    )
    for n in ctx.get("notes", []):
        parts.append(f"<div class='note'>{_e(n)}</div>")
    for m, why in ctx.get("failed", {}).items():
        parts.append(f"<div class='note fail'><b>{_e(m)} failed:</b> {_e(why)}</div>")

    if ctx.get("viewer"):  # the interactive viewer (report/viewer.py)
        from .viewer import viewer_html

        parts.append(viewer_html(ctx["viewer"]))

    # metrics table
    parts.append("<h2>Error against ground truth</h2>")
    parts.append(
        "<div class='sub'>Visibility V in [0,1]; errors are V - V_ref over surface pixels "
        "(background excluded). Click a column header to sort. Hover a header for its meaning.</div>"
    )
    ronly = [m["name"] for m in methods if "receivers" in m["metrics"]]
    if ronly:
        parts.append(
            "<div class='note'>"
            + ", ".join(f"<b>{_e(n)}</b>" for n in ronly)
            + " shade only receivers by design (no self-shadowing; occluder-only geometry gets V = 1). "
            "Each such method has two rows: <i>all surfaces</i> (every surface pixel: the method's limit "
            "included) and <i>receivers only</i> (pixels of faces with role receiver or both: its quality "
            "where it applies).</div>"
        )
    header = (
        [("method", "")]
        + [(k, METRIC_HELP.get(k, k)) for k in METRIC_COLS]
        + [
            ("px shadow", "pixels in umbra or penumbra of either image (the ssm_error set)"),
            ("total ms", "frame time, all phases, after JIT warm-up"),
        ]
    )
    rows = []
    for m in methods:
        mt = m["metrics"]
        name = _e(m["name"])
        labelled = [(m["name"], mt)]
        if "receivers" in mt:
            labelled = [(m["name"] + " (all surfaces)", mt), (m["name"] + " (receivers only)", mt["receivers"])]
        for label, x in labelled:
            shown = _e(label)
            if ctx.get("viewer"):
                shown = f'<a href="#viewer?m={name}" title="show in the viewer">{shown}</a>'
            rows.append(
                [(shown, _e(label))]
                + [x.get(k) for k in METRIC_COLS]
                + [x.get("n_shadow"), _ms(m["timings"].get("total", float("nan")) * 1e3)]
            )
    parts.append(_table("metrics", header, rows))
    if methods:
        mt = methods[0]["metrics"]
        parts.append(
            f"<div class='sub'>Ground-truth regions (eps = {mt.get('eps', 0.001):g}): "
            f"{mt.get('n_umbra', 0):,} umbra, {mt.get('n_penumbra', 0):,} penumbra, {mt.get('n_lit', 0):,} lit "
            f"of {mt.get('n_pixels', 0):,} surface pixels.</div>"
        )

    # timings table (long format: stays narrow whatever the number of phases)
    parts.append("<h2>Time per phase (milliseconds)</h2>")
    parts.append(
        "<div class='sub'>One frame per method after a JIT warm-up render. <code>eye_gbuffer</code> and "
        "<code>shading</code> are shared by all methods (<i>shared</i> column); <i>method ms</i> is the "
        "frame minus them. For repeated timings with spread and ratios use <code>softshadows bench</code>."
        "</div>"
    )
    allm = [ref] + list(methods)
    header = [
        ("method", ""),
        ("phase", "a timed phase of the frame"),
        ("ms", "milliseconds"),
        ("% of frame", "share of the whole frame"),
        ("shared", "phase common to all methods"),
    ]
    rows = []
    for m in allm:
        tot = m["timings"].get("total", float("nan"))
        for p, t in m["timings"].items():
            if p == "total":
                continue
            shared = p in ("eye_gbuffer", "shading")
            rows.append(
                [
                    (_e(m["name"]), _e(m["name"])),
                    (_e(p), _e(p)),
                    _ms(t * 1e3),
                    _ms(100.0 * t / tot if tot > 0 else None),
                    ("yes" if shared else "", "1" if shared else "0"),
                ]
            )
    summary = [
        ("method", ""),
        ("total ms", "whole frame"),
        ("method ms", "frame minus eye_gbuffer and shading"),
        ("slowest phase", ""),
    ]
    srows = []
    for m in allm:
        t = m["timings"]
        own = {k: v for k, v in t.items() if k not in ("total", "eye_gbuffer", "shading")}
        slow = max(own, key=own.get) if own else ""
        srows.append(
            [
                (_e(m["name"]), _e(m["name"])),
                _ms(t.get("total", float("nan")) * 1e3),
                _ms((t.get("total", float("nan")) - t.get("eye_gbuffer", 0.0) - t.get("shading", 0.0)) * 1e3),
                (_e(slow), _e(slow)),
            ]
        )
    parts.append(
        "<div class='meta'><div>"
        + _table("timesum", summary, srows)
        + "</div><div>"
        + _table("timings", header, rows)
        + "</div></div>"
    )

    if ctx.get("grid"):
        parts.append("<h2>All methods</h2>")
        parts.append(f"<div class='grid'><img alt='comparison grid' src='{data_uri(ctx['grid'])}'></div>")

    parts.append("<h2>Per method</h2>")
    parts.append(
        f"<div class='sub'>Error maps share the colour limits &plusmn;{ctx['error_limit']:.2f}: "
        "<span style='color:#b2182b'><b>red = darker than truth</b></span>, "
        "<span style='color:#2166ac'><b>blue = brighter than truth</b></span>, grey = background.</div>"
    )
    if ctx.get("colorbar"):
        parts.append(f"<img alt='error colour scale' src='{data_uri(ctx['colorbar'])}'>")
    parts.append("<div class='cards'>")
    for m in [ref] + list(methods):
        figs = []
        for key, cap in (("image", "shaded"), ("v", "V"), ("error_raw", "signed error")):
            if m["images"].get(key):
                figs.append(
                    f"<figure><img alt='{_e(m['name'])} {cap}' src='{data_uri(m['images'][key])}'>"
                    f"<figcaption>{cap}</figcaption></figure>"
                )
        mt = m.get("metrics")
        line = (
            f"MAE {mt['mae']:.4f} &middot; ssm {mt['ssm_error']:.4f} &middot; FLIP {mt.get('flip', float('nan')):.4f}"
            if mt
            else "reference"
        )
        if mt and "receivers" in mt:
            rc = mt["receivers"]
            line = (
                f"all surfaces: {line}<br>receivers only: MAE {rc['mae']:.4f} &middot; ssm {rc['ssm_error']:.4f}"
                f" &middot; FLIP {rc.get('flip', float('nan')):.4f}"
            )
        parts.append(
            f"<div class='card'><h3>{_e(m['name'])}</h3><div class='sub'>{_e(m.get('summary', ''))}"
            f"<br><i>{_e(m.get('paper', ''))}</i><br>{line} &middot; "
            f"{m['timings'].get('total', float('nan')) * 1e3:.1f} ms</div>"
            f"<div class='imgs'>{''.join(figs)}</div>"
            f"<details open><summary>parameters</summary>{_kv(m['params'])}</details>"
            f"<details><summary>statistics</summary>{_kv(m.get('stats', {}))}</details></div>"
        )
    parts.append("</div>")

    parts.append("<h2>Scene and machine</h2><div class='meta'>")
    parts.append(f"<div><h3>scene</h3>{_kv(sc)}</div>")
    mi = dict(ctx["machine"])
    vers = mi.pop("versions", {})
    parts.append(f"<div><h3>machine</h3>{_kv(mi)}</div><div><h3>versions</h3>{_kv(vers)}</div></div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_html(path, ctx: dict) -> str:
    from ..io import write_text

    return write_text(path, render_html(ctx))
