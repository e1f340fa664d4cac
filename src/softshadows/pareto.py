"""``pareto``: error against frame time over every method's quality settings, the Pareto front, and
the time-budget choice behind ``softshadows render --method auto --budget-ms X``.

    softshadows pareto [SCENE] --methods all|a,b --size WxH --light rect|sphere -o DIR
                       [--samples N] [--seed S] [--repeats R] [--budget-ms X]

Each method's settings come from its ``sweep`` (declared beside its ``params``, see
``Method.sweep_settings``). The ground truth is rendered once (``--samples``, with a seed other than
the sweep's so the ground-truth settings get their honest noise). Every setting is rendered once
untimed (JIT warm-up, cold caches; its V gives the MAE), then ``repeats`` timed rounds visit every
setting once each, round-robin with a shifted start (interleaved: drift and load spread over all);
``ms`` is the median frame time (``total``: G-buffer, method, shading). ``pareto.json`` is
rewritten atomically after every render, so Ctrl-C leaves the results so far.

Outputs in ``-o DIR``: ``pareto.json``, ``pareto.png`` (log-log, per method, the front),
``pareto.md`` and a self-contained ``pareto.html``. A complete run of all methods also stores the
front in the cache (:func:`cache_path`) that ``--method auto`` reads. Docs: docs/viewer-and-pareto.md.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import statistics
import sys
import time

import numpy as np

from .compare import DEFAULT_GT_SAMPLES, DEFAULT_SCENE, DEFAULT_SIZE, REFERENCE, jsonable, load, resolve_methods
from .errors import SoftShadowsError

DEFAULT_OUT = "softshadows-pareto"
DEFAULT_REPEATS = 3
SCHEMA = 1
REF_SEED_OFFSET = 7919  # the reference's seed = seed + this: never the same samples as a swept ground truth


# ---- the front and the budget choice ---------------------------------------------------------------
def _finite(x) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def pareto_mask(ms, mae) -> np.ndarray:
    """Boolean mask of the non-dominated points (both coordinates minimised): a point is dominated
    when another is no slower and no worse, and better in one. Points with a missing/NaN coordinate
    are never on the front. O(n log n): sort by time, keep the running best error."""
    ms = np.asarray([x if _finite(x) else np.nan for x in ms], np.float64)
    mae = np.asarray([x if _finite(x) else np.nan for x in mae], np.float64)
    n = len(ms)
    on = np.zeros(n, bool)
    ok = np.flatnonzero(np.isfinite(ms) & np.isfinite(mae))
    order = ok[np.lexsort((mae[ok], ms[ok]))]
    best_before = math.inf  # least error among strictly faster points
    i = 0
    while i < len(order):
        j = i
        while j < len(order) and ms[order[j]] == ms[order[i]]:
            j += 1
        group = order[i:j]  # equal times, sorted by error
        gmin = mae[group[0]]
        if gmin < best_before:
            on[group[mae[group] == gmin]] = True
        best_before = min(best_before, gmin)
        i = j
    return on


def mark_front(points: list[dict]) -> list[dict]:
    """Set ``on_front`` on every point (dicts with ``ms`` and ``mae``); returns ``points``."""
    mask = pareto_mask([p.get("ms") for p in points], [p.get("mae") for p in points])
    for p, m in zip(points, mask):
        p["on_front"] = bool(m)
    return points


def choose(points: list[dict], budget_ms: float) -> tuple[dict, bool]:
    """(the point to use within ``budget_ms``, whether it fits). Fitting: the least error among the
    front's points whose time is within the budget (ties: the faster), so never a dominated point;
    when none fits, the fastest point (ties: the less error) and False."""
    if not _finite(budget_ms) or budget_ms <= 0:
        raise SoftShadowsError(f"--budget-ms must be a positive number of milliseconds, got {budget_ms!r}")
    mask = pareto_mask([p.get("ms") for p in points], [p.get("mae") for p in points])
    front = [p for p, m in zip(points, mask) if m]
    if not front:
        raise SoftShadowsError("no measured point to choose from (the sweep produced no timing and error)")
    fits = [p for p in front if p["ms"] <= budget_ms]
    if fits:
        return min(fits, key=lambda p: (p["mae"], p["ms"])), True
    return min(front, key=lambda p: (p["ms"], p["mae"])), False


def describe(p: dict) -> str:
    prm = " ".join(f"{k}={v}" for k, v in p["params"].items())
    return f"{p['method']}{(' ' + prm) if prm else ''} ({p['ms']:.1f} ms, MAE {p['mae']:.4f})"


# ---- writing ----------------------------------------------------------------------------------
def atomic_write(path, data) -> None:
    """Write ``data`` (str or bytes) atomically (softshadows.io: temp file beside it, renamed): a
    reader or an interrupted run sees the old file or the new one, never half of one."""
    from .io import write_bytes, write_text

    (write_text if isinstance(data, str) else write_bytes)(path, data)


def plot_png(doc: dict) -> bytes:
    """Log-log error against time: each method's settings (joined in time order), the front."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [p for p in doc["points"] if _finite(p.get("ms")) and _finite(p.get("mae"))]
    fig, ax = plt.subplots(figsize=(8.0, 5.4), dpi=110)
    floor = 1e-5  # log axes: an exact 0 error is drawn at this floor
    methods = list(dict.fromkeys(p["method"] for p in pts))
    colors = plt.get_cmap("tab10")
    for i, m in enumerate(methods):
        mp = sorted((p for p in pts if p["method"] == m), key=lambda p: p["ms"])
        ax.plot(
            [p["ms"] for p in mp],
            [max(p["mae"], floor) for p in mp],
            "o-",
            color=colors(i % 10),
            lw=0.8,
            ms=4.5,
            alpha=0.85,
            label=m,
        )
    front = sorted((p for p in pts if p.get("on_front")), key=lambda p: p["ms"])
    if front:
        ax.plot(
            [p["ms"] for p in front],
            [max(p["mae"], floor) for p in front],
            "k--",
            drawstyle="steps-post",
            lw=1.2,
            label="Pareto front",
        )
        ax.plot([p["ms"] for p in front], [max(p["mae"], floor) for p in front], "o", mfc="none", mec="k", ms=9)
    b = doc.get("budget")
    if b and _finite(b.get("budget_ms")):
        ax.axvline(b["budget_ms"], color="#c00", lw=1, ls=":", label=f"budget {b['budget_ms']:g} ms")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("frame time (ms, median of repeats)")
    ax.set_ylabel("MAE of V against ground truth")
    sc = doc.get("scene", {})
    done = "" if doc.get("complete") else "  (partial)"
    ax.set_title(f"{sc.get('name', '?')}, {doc.get('light', '?')} light, {doc['size'][0]}x{doc['size'][1]}{done}")
    ax.grid(True, which="both", alpha=0.25)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def _fmt_params(p: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in p.items()) or "(defaults)"


def table_md(doc: dict) -> str:
    pts = sorted(doc["points"], key=lambda p: p["ms"] if _finite(p.get("ms")) else math.inf)
    lines = ["| method | params | ms | MAE | on front |", "|---|---|---:|---:|:---:|"]
    for p in pts:
        ms = f"{p['ms']:.2f}" if _finite(p.get("ms")) else "–"
        mae = f"{p['mae']:.5f}" if _finite(p.get("mae")) else "–"
        lines.append(
            f"| {p['method']} | {_fmt_params(p['params'])} | {ms} | {mae} | {'yes' if p.get('on_front') else ''} |"
        )
    return "\n".join(lines) + "\n"


def point_label(p: dict) -> str:
    """How a setting is named in the page's viewer and table links."""
    return f"{p['method']} {_fmt_params(p['params'])}"


def pareto_html(doc: dict, plot: bytes | None, viewer: dict | None = None) -> str:
    """A self-contained page: the plot (data URI), the budget choice, the viewer of the front's
    settings against the reference (``viewer``: report.viewer.viewer_payload), the sortable table."""
    import html as _h
    from urllib.parse import quote

    from .report.html import _CSS, _JS, _kv, _ms, _table, data_uri

    e = _h.escape
    sc = doc.get("scene", {})
    title = (
        f"softshadows pareto: {sc.get('name', '?')} ({doc.get('light', '?')} light), {doc['size'][0]}x{doc['size'][1]}"
    )
    parts = [
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{e(title)}</title>",
        f"<style>{_CSS}</style><script>{_JS}</script></head><body><h1>{e(title)}</h1>",
        f"<div class='sub'>{e(doc.get('created', ''))} &middot; reference: ground truth, "
        f"{doc['reference']['samples']} samples &middot; {doc['repeats']} timed repeat(s) per setting, interleaved, "
        "after an untimed warm-up frame; ms = median"
        + (f" &middot; <code>{e(doc['command'])}</code>" if doc.get("command") else "")
        + "</div>",
    ]
    if not doc.get("complete"):
        parts.append("<div class='note'>partial results: the sweep was interrupted or is still running</div>")
    b = doc.get("budget")
    if b:
        parts.append(f"<div class='note'>budget {b['budget_ms']:g} ms: <b>{e(b['text'])}</b></div>")
    if plot:
        parts.append(f"<h2>Error against frame time</h2><img alt='pareto plot' src='{data_uri(plot)}'>")
    if viewer:
        from .report.viewer import viewer_html

        parts.append(viewer_html(viewer).replace(">Viewer</h2>", ">The front's settings against the reference</h2>", 1))
    header = [
        ("method", ""),
        ("params", "the swept parameters (others at their defaults)"),
        ("ms", "median frame time"),
        ("MAE", "mean |V - V_ref| over surface pixels"),
        ("on front", "no other setting is both as fast and as accurate"),
    ]
    rows = []
    for p in doc["points"]:
        fr = bool(p.get("on_front"))
        name = e(p["method"])
        if fr and viewer:
            name = f'<a href="#viewer?m={e(quote(point_label(p)))}" title="show in the viewer">{name}</a>'
        rows.append(
            [
                (name, e(p["method"])),
                (e(_fmt_params(p["params"])), e(_fmt_params(p["params"]))),
                _ms(p["ms"] if _finite(p.get("ms")) else None),
                p.get("mae"),
                ("yes" if fr else "", "1" if fr else "0"),
            ]
        )
    parts.append("<h2>Settings</h2>" + _table("pareto", header, rows))
    mi = dict(doc.get("machine", {}))
    mi.pop("versions", None)
    parts.append(f"<h2>Scene and machine</h2><div class='meta'><div>{_kv(sc)}</div><div>{_kv(mi)}</div></div>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_outputs(doc: dict, out_dir, final: bool = True, viewer: dict | None = None) -> dict:
    """pareto.json always; with ``final`` also the plot, the markdown table and pareto.html."""
    os.makedirs(out_dir, exist_ok=True)
    files = {"json": os.path.join(out_dir, "pareto.json")}
    atomic_write(files["json"], json.dumps(jsonable(doc), indent=2))
    if final:
        png = plot_png(doc)
        files.update(
            png=os.path.join(out_dir, "pareto.png"),
            md=os.path.join(out_dir, "pareto.md"),
            html=os.path.join(out_dir, "pareto.html"),
        )
        atomic_write(files["png"], png)
        atomic_write(files["md"], table_md(doc))
        atomic_write(files["html"], pareto_html(doc, png, viewer))
    return files


# ---- the cache of fronts (render --method auto) -------------------------------------------------
def cache_dir() -> str:
    """``$SOFTSHADOWS_CACHE_DIR``, else ``$XDG_CACHE_HOME/softshadows``, else ``~/.cache/softshadows``."""
    d = os.environ.get("SOFTSHADOWS_CACHE_DIR")
    if d:
        return d
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "softshadows")


def scene_hash(scene) -> str:
    """sha256 of what a frame depends on: geometry and roles, albedos, camera, light."""
    h = hashlib.sha256()
    f = scene.flat
    for a in (f.vertices, f.faces, f.occluder, f.receiver, f.mesh_id, f.albedo):
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    cam = scene.camera
    lt = scene.light
    light = {
        k: np.asarray(getattr(lt, k)).tolist() for k in ("center", "u", "v", "radius", "intensity") if hasattr(lt, k)
    }
    h.update(
        json.dumps(
            {
                "camera": [np.asarray(cam.eye).tolist(), np.asarray(cam.target).tolist(), np.asarray(cam.up).tolist()],
                "fov": float(cam.fov_y),
                "light": [lt.shape, light],
            },
            sort_keys=True,
        ).encode()
    )
    return h.hexdigest()


def machine_id() -> str:
    """A short stable id of this machine: /etc/machine-id (when readable), CPU model, cores, arch."""
    parts = [platform.machine(), platform.node()]
    for p in ("/etc/machine-id", "/var/lib/dbus/machine-id"):
        try:
            with open(p) as fh:
                parts.append(fh.read().strip())
            break
        except OSError:
            pass
    from .report.html import machine_info

    mi = machine_info()
    parts += [str(mi.get("cpu")), str(mi.get("usable_cores", mi.get("logical_cores")))]
    return hashlib.sha256("|".join(parts).encode()).hexdigest()[:16]


def cache_key(scene, width: int, height: int) -> dict:
    from . import __version__

    return {
        "version": __version__,
        "scene": scene_hash(scene),
        "light": scene.light.shape,
        "size": [int(width), int(height)],
        "machine": machine_id(),
    }


def cache_path(scene, width: int, height: int) -> str:
    key = cache_key(scene, width, height)
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]
    safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in str(scene.name))[:40] or "scene"
    return os.path.join(cache_dir(), "pareto", f"{safe}-{scene.light.shape}-{width}x{height}-{digest}.json")


def load_cached(scene, width: int, height: int) -> dict | None:
    """The cached front of this scene, size, machine and project version, or None."""
    path = cache_path(scene, width, height)
    try:
        with open(path) as fh:
            doc = json.load(fh)
    except (OSError, ValueError):
        return None
    if doc.get("key") != cache_key(scene, width, height) or not doc.get("complete"):
        return None
    return doc


def store_cached(doc: dict, scene, width: int, height: int) -> str:
    path = cache_path(scene, width, height)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    atomic_write(path, json.dumps(jsonable({**doc, "key": cache_key(scene, width, height)}), indent=1))
    return path


# ---- the sweep ----------------------------------------------------------------------------------
def _mae(v, v_ref) -> float:
    from .metrics import compute_metrics

    return float(compute_metrics(v, v_ref)["mae"])


def pareto(
    scene=DEFAULT_SCENE,
    methods="all",
    width: int = DEFAULT_SIZE[0],
    height: int = DEFAULT_SIZE[1],
    out_dir=None,
    gt_samples: int = DEFAULT_GT_SAMPLES,
    *,
    light: str | None = None,
    seed: int = 0,
    repeats: int = DEFAULT_REPEATS,
    sweeps: dict | None = None,
    budget_ms: float | None = None,
    cache: bool | None = None,
    progress: bool = False,
    verbose: bool = False,
    command: str | None = None,
) -> dict:
    """Measure every setting of every method (``"all"`` includes the ground truth as a contender),
    return the document written to ``pareto.json``: ``points`` (``method``, ``params``, ``ms``,
    ``mae``, ``on_front``, ``times_ms``), ``front`` (indices), scene, machine, and ``budget`` when
    ``budget_ms`` is given. ``sweeps`` = {method: sweep} overrides declared sweeps (a dict of lists
    or a list of settings, as ``Method.sweep``). ``out_dir``: where the files go (None: nowhere).
    ``cache``: store the complete front for ``--method auto`` (default: when ``methods == "all"``
    and no sweep is overridden)."""
    from . import __version__, render
    from .compare import scene_info
    from .methods import get_method
    from .report.html import machine_info

    if not isinstance(repeats, int) or repeats < 1:
        raise SoftShadowsError(f"--repeats must be a positive integer, got {repeats!r}")
    if budget_ms is not None and (not _finite(budget_ms) or budget_ms <= 0):
        raise SoftShadowsError(f"--budget-ms must be a positive number of milliseconds, got {budget_ms!r}")
    sc = load(scene, light)
    names, skipped = resolve_methods(methods, sc.light.shape, include_reference=True)
    sweeps = dict(sweeps or {})
    for m in sweeps:
        if m not in names:
            raise SoftShadowsError(f"sweep given for method '{m}', which is not being measured")
    settings = [(m, s) for m in names for s in get_method(m).sweep_settings(sweeps.get(m))]
    ref_params = get_method(REFERENCE).resolve_params({"samples": gt_samples})
    if cache is None:
        cache = methods == "all" and not sweeps
    points = [
        {"method": m, "params": s, "ms": None, "mae": None, "on_front": False, "times_ms": []} for m, s in settings
    ]
    doc = {
        "schema": SCHEMA,
        "version": __version__,
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
        "command": command,
        "scene": scene_info(sc, width, height),
        "light": sc.light.shape,
        "size": [int(width), int(height)],
        "reference": {"method": REFERENCE, "samples": ref_params["samples"], "seed": seed + REF_SEED_OFFSET},
        "seed": seed,
        "repeats": repeats,
        "skipped": skipped,
        "machine": machine_info(),
        "machine_id": machine_id(),
        "complete": False,
        "points": points,
        "front": [],
    }

    def say(msg):
        if verbose:
            print(msg, file=sys.stderr, flush=True)

    def save(final=False):
        mark_front(points)
        doc["front"] = [i for i, p in enumerate(points) if p["on_front"]]
        if final and budget_ms is not None and doc["front"]:
            p, fits = choose(points, budget_ms)
            doc["budget"] = {
                "budget_ms": budget_ms,
                "fits": fits,
                "method": p["method"],
                "params": p["params"],
                "ms": p["ms"],
                "mae": p["mae"],
                "text": (describe(p) if fits else f"nothing fits; the fastest is {describe(p)}"),
            }
        if out_dir is not None:
            return write_outputs(doc, out_dir, final=final, viewer=_viewer() if final else None)
        return {}

    frames: dict = {}  # setting index -> (V, sRGB image) of its warm-up frame, for the page's viewer

    def _viewer():
        from .compare import _png_bytes
        from .metrics import signed_error_map
        from .report import error_limit
        from .report.viewer import viewer_payload
        from .shading import to_srgb8

        front = sorted((i for i in doc["front"] if i in frames), key=lambda i: points[i]["ms"])
        items = [
            {"name": REFERENCE, "v": ref.visibility, "image": _png_bytes(to_srgb8(ref.image)), "caption": "reference"}
        ]
        for i in front:
            p = points[i]
            items.append(
                {
                    "name": point_label(p),
                    "v": frames[i][0],
                    "image": _png_bytes(frames[i][1]),
                    "caption": f"{p['ms']:.1f} ms, MAE {p['mae']:.4f}",
                }
            )
        limit = error_limit([signed_error_map(frames[i][0], ref.visibility) for i in front])
        return viewer_payload(items, limit)

    say(f"{sc.name} ({sc.light.shape} light) {width}x{height}: {len(settings)} settings of {len(names)} method(s)")
    say(f"  ground truth reference, {ref_params['samples']} samples ...")
    ref = render(sc, REFERENCE, width, height, seed=seed + REF_SEED_OFFSET, progress=progress, **ref_params)
    doc["reference"]["ms"] = ref.timings["total"] * 1e3
    from tqdm import tqdm

    from .shading import to_srgb8

    bar = tqdm(total=len(settings) * (1 + repeats), desc="pareto", unit="frame", disable=not progress, leave=False)
    files: dict = {}
    try:
        for i, (m, s) in enumerate(settings):  # warm-up frame (untimed) and the error
            bar.set_postfix_str(f"{m} {_fmt_params(s)}", refresh=False)
            try:
                r = render(sc, m, width, height, seed=seed, **s)
            except SoftShadowsError:
                raise
            except Exception as exc:  # one failing setting (e.g. out of memory) does not end the sweep
                points[i]["failed"] = f"{type(exc).__name__}: {exc}"
                print(f"softshadows: warning: {m} {_fmt_params(s)} failed: {points[i]['failed']}", file=sys.stderr)
                bar.update(1 + repeats)
                continue
            points[i]["mae"] = _mae(r.visibility, ref.visibility)
            frames[i] = (r.visibility, to_srgb8(r.image))
            bar.update()
            save()
        n = len(settings)
        for rep in range(repeats):  # interleaved timed rounds; each starts at another setting
            for k in range(n):
                i = (k + rep * max(1, n // repeats)) % n
                m, s = settings[i]
                if "failed" in points[i]:
                    continue
                bar.set_postfix_str(f"{m} {_fmt_params(s)}", refresh=False)
                r = render(sc, m, width, height, seed=seed, **s)
                points[i]["times_ms"].append(r.timings["total"] * 1e3)
                points[i]["ms"] = statistics.median(points[i]["times_ms"])
                bar.update()
                save()
        doc["complete"] = True
    finally:
        bar.close()
        files = save(final=True)  # also on Ctrl-C: the partial plot, table and page
    if cache and doc["complete"]:
        doc["cache"] = store_cached(doc, sc, width, height)
    doc["files"] = files
    return doc


# ---- render --method auto ----------------------------------------------------------------------------
def auto_choice(scene, width: int, height: int, budget_ms, *, progress: bool = False, verbose: bool = True):
    """(method, params, point, fits, cache file) for ``render --method auto``: the cached front of
    this scene/size/machine/version, measured (all methods, declared sweeps) when missing."""
    if budget_ms is None:
        raise SoftShadowsError("--method auto needs --budget-ms (the frame budget in milliseconds)")
    if not _finite(budget_ms) or budget_ms <= 0:
        raise SoftShadowsError(f"--budget-ms must be a positive number of milliseconds, got {budget_ms!r}")
    doc = load_cached(scene, width, height)
    path = cache_path(scene, width, height)
    if doc is None:
        if verbose:
            print(
                f"softshadows: no measured front for {scene.name} at {width}x{height} on this machine; "
                f"measuring it once (cached in {path}) ...",
                file=sys.stderr,
                flush=True,
            )
        doc = pareto(scene, "all", width, height, None, cache=True, progress=progress, verbose=verbose)
    p, fits = choose(doc["points"], budget_ms)
    return p["method"], dict(p["params"]), p, fits, path


# ---- command line -----------------------------------------------------------------------------
def _cmd_pareto(args) -> int:
    from .compare import parse_size

    w, h = parse_size(args.size)
    argv = ["softshadows", "pareto"] + list(getattr(args, "_argv", []) or [])
    doc = pareto(
        args.scene,
        args.methods,
        w,
        h,
        args.output,
        args.samples,
        light=args.light,
        seed=args.seed,
        repeats=args.repeats,
        budget_ms=args.budget_ms,
        progress=not args.quiet,
        verbose=not args.quiet,
        command=" ".join(argv) if len(argv) > 2 else None,
    )
    if not args.quiet:
        print(f"{'method':<20}{'params':<40}{'ms':>9}{'MAE':>10}  front")
        for p in sorted(doc["points"], key=lambda p: p["ms"] if _finite(p["ms"]) else math.inf):
            if "failed" in p:
                print(f"{p['method']:<20}{_fmt_params(p['params']):<40} failed: {p['failed']}")
                continue
            print(
                f"{p['method']:<20}{_fmt_params(p['params']):<40}{p['ms']:9.2f}{p['mae']:10.5f}"
                f"  {'*' if p['on_front'] else ''}"
            )
        if doc.get("cache"):
            print(f"front cached for --method auto: {doc['cache']}")
    if doc.get("budget"):
        print(f"budget {args.budget_ms:g} ms: {doc['budget']['text']}")
    print(f"report: {os.path.abspath(doc['files']['html'])}")
    return 0


def register_cli(subparsers) -> None:
    p = subparsers.add_parser(
        "pareto",
        help="error vs frame time over every method's quality settings; the Pareto front; --budget-ms",
        description="Sweep each method's quality settings (declared per method), measure frame time "
        "(interleaved, after warm-up, median of repeats) and MAE against one ground-truth render; write "
        "pareto.json, pareto.png, pareto.md and pareto.html.",
    )
    p.add_argument(
        "scene",
        nargs="?",
        default=DEFAULT_SCENE,
        help=f"built-in name, TOML scene or mesh file (default {DEFAULT_SCENE})",
    )
    p.add_argument(
        "--methods", default="all", help="'all' (default, the ground truth included) or a comma-separated list"
    )
    p.add_argument("--size", default=f"{DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]}", help="WxH (default %(default)s)")
    p.add_argument("--light", choices=("rect", "sphere"), default=None, help="swap in this light shape")
    p.add_argument("-o", "--output", default=DEFAULT_OUT, help="output directory (default %(default)s)")
    p.add_argument("--samples", type=int, default=DEFAULT_GT_SAMPLES, help="reference light samples per pixel (N x N)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--repeats", type=int, default=DEFAULT_REPEATS, help="timed frames per setting (default %(default)s)"
    )
    p.add_argument(
        "--budget-ms",
        dest="budget_ms",
        type=float,
        default=None,
        help="print the least-error setting within this frame time",
    )
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=_cmd_pareto)
