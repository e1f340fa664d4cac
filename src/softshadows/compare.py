"""``compare``: render ground truth once and each method on one scene, measure and show the differences.

    softshadows compare [SCENE] --methods all|a,b,c --size WxH --light rect|sphere -o DIR
                        [--set method.key=value ...] [--samples N] [--seed S]

With no arguments (``softshadows compare``, also what a bare ``softshadows`` runs) it compares
every registered method on the default scene (:data:`DEFAULT_SCENE`, rect light) at
:data:`DEFAULT_SIZE`, writes ``./softshadows-report/`` and prints where ``report.html`` is.

Files written to ``out_dir``:

* ``ground-truth.png``, ``ground-truth_V.png`` — the reference (shaded image, V as grey);
* per method ``<name>.png``, ``<name>_V.png``, ``<name>_error.png`` (signed-error heat map with a
  colorbar, shared symmetric limits: red = darker than truth, blue = brighter);
* ``grid.png`` — one labelled image of everything; ``metrics.json`` — metrics, per-phase
  timings, parameters, statistics, scene and machine; ``report.html`` — all of it, self-contained.

A method that by design shades only receivers (``Method.receivers_only``: the soft shadow map
computes no self-shadowing) is measured twice: over all surface pixels (``metrics``, the method's
limit included) and over receiver pixels only (``metrics["receivers"]``, its quality where it
applies); the report, the CLI table and ``metrics.json`` show both, labelled.

Methods whose light shapes do not include the scene's light are skipped with a note in the report;
a method that fails at run time is reported (note + stderr) and the others still run.
"""

from __future__ import annotations

import math
import os
import sys
import time
import traceback

import numpy as np

from .errors import SoftShadowsError
from .io import check_folder, write_bytes, write_json

DEFAULT_SCENE = "bunny"
DEFAULT_SIZE = (320, 240)
DEFAULT_OUT = "softshadows-report"
DEFAULT_GT_SAMPLES = 256
REFERENCE = "ground-truth"


# ---- argument helpers (shared with bench) -------------------------------------------------------
def parse_size(text) -> tuple[int, int]:
    """'WxH' -> (w, h); the CLI's parser (one definition for every subcommand)."""
    from .cli import parse_size as _ps

    return _ps(text)


def resolve_methods(spec, light_shape: str | None = None, include_reference: bool = False):
    """``"all"`` | ``"a,b,c"`` | list -> (names to run, {skipped name: reason}).

    ``all`` means every registered method except the ground truth (unless ``include_reference``);
    names are checked against the registry (unknown -> SoftShadowsError); methods whose light
    shapes do not include ``light_shape`` are skipped with a reason."""
    from .methods import methods as registry

    reg = registry()
    if spec is None:
        spec = "all"
    if isinstance(spec, str):
        names = [s.strip() for s in spec.split(",") if s.strip()]
    else:
        names = [str(s) for s in spec]
    if not names:
        raise SoftShadowsError("--methods is empty; give 'all' or a comma-separated list of method names")
    out: list[str] = []
    for n in names:
        if n == "all":
            out += [k for k in reg if (include_reference or k != REFERENCE)]
        elif n not in reg:
            raise SoftShadowsError(f"unknown method '{n}'; valid: all, {', '.join(reg)}")
        else:
            out.append(n)
    seen, run, skipped = set(), [], {}
    for n in out:
        if n in seen:
            continue
        seen.add(n)
        m = reg[n]
        if light_shape is not None and light_shape not in m.light_shapes:
            skipped[n] = (
                f"{n} supports {' and '.join(m.light_shapes)} lights only; the scene has a "
                f"{light_shape} light (use --light {m.light_shapes[0]} to include it)"
            )
            continue
        run.append(n)
    return run, skipped


def parse_method_sets(items) -> dict[str, dict[str, str]]:
    """['method.key=value', ...] -> {method: {key: value}} (values coerced later by each Param)."""
    out: dict[str, dict[str, str]] = {}
    for it in items or []:
        if "=" not in it or "." not in it.split("=", 1)[0]:
            raise SoftShadowsError(f"--set expects method.key=value (e.g. pcss.filter_samples=32), got '{it}'")
        lhs, val = it.split("=", 1)
        meth, key = lhs.split(".", 1)
        meth, key = meth.strip(), key.strip()
        if not meth or not key:
            raise SoftShadowsError(f"--set expects method.key=value, got '{it}'")
        out.setdefault(meth, {})[key] = val.strip()
    return out


def load(scene, light=None):
    """A Scene from a Scene, a built-in name or a file, with the light swapped to ``light``."""
    from .scene.types import Scene

    if isinstance(scene, Scene):
        if light is None:
            return scene
        from .scene.builtin import with_light_shape

        return with_light_shape(scene, light)
    from . import load_scene

    return load_scene(scene, light=light)


def jsonable(x):
    """Plain JSON types (NaN/inf -> None, numpy -> Python, big arrays dropped, '_' keys dropped)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items() if not str(k).startswith("_")}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist()) if x.size <= 64 else f"<array {x.shape}>"
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        f = float(x)
        return f if math.isfinite(f) else None
    return x


def scene_info(scene, width, height) -> dict:
    flat = scene.flat
    lt = scene.light
    if lt.shape == "rect":
        ldesc = (
            f"rect {np.linalg.norm(lt.u):.3g} x {np.linalg.norm(lt.v):.3g} at "
            f"({', '.join(f'{c:.3g}' for c in lt.center)}), facing ({', '.join(f'{c:.2g}' for c in lt.normal)})"
        )
    else:
        ldesc = f"sphere radius {lt.radius:.3g} at ({', '.join(f'{c:.3g}' for c in lt.center)})"
    cam = scene.camera
    return {
        "name": scene.name,
        "size": [int(width), int(height)],
        "triangles": int(len(flat.faces)),
        "occluder_triangles": int(flat.occluder.sum()),
        "receiver_triangles": int(flat.receiver.sum()),
        "meshes": ", ".join(f"{m.name} ({m.role}, {len(m.faces)})" for m in scene.meshes),
        "light": ldesc,
        "camera": (
            f"eye ({', '.join(f'{c:.3g}' for c in cam.eye)}), target "
            f"({', '.join(f'{c:.3g}' for c in cam.target)}), fov_y {cam.fov_y:g}"
        ),
    }


def _png_bytes(rgb8: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb8).save(buf, format="PNG")
    return buf.getvalue()


def _write(path, data: bytes) -> None:
    write_bytes(path, data)


# ---- the comparison ---------------------------------------------------------------------------
def compare(
    scene=DEFAULT_SCENE,
    methods="all",
    width: int = DEFAULT_SIZE[0],
    height: int = DEFAULT_SIZE[1],
    out_dir=DEFAULT_OUT,
    params_by_method: dict | None = None,
    gt_samples: int = DEFAULT_GT_SAMPLES,
    *,
    light: str | None = None,
    seed: int = 0,
    progress: bool = False,
    verbose: bool = False,
    command: str | None = None,
) -> dict:
    """Render ``ground-truth`` (``gt_samples`` light samples) once and each of ``methods``
    (``"all"``, ``"a,b"`` or a list) on ``scene`` (a Scene, built-in name or file; ``light``
    swaps its light shape) at ``width`` x ``height``; write images, heat maps, ``grid.png``,
    ``metrics.json`` and ``report.html`` into ``out_dir``.

    ``params_by_method`` = {method: {param: value}}. Returns a dict with ``out_dir``, ``report``,
    ``files``, ``metrics``/``timings``/``params``/``stats`` by method, ``skipped``, ``failed``,
    ``timed_while_compiling`` (a cold cache: a second process compiled while the frames were
    timed; :data:`COMPILING_NOTE`).
    """
    from .methods import get_method

    sc = load(scene, light)
    names, skipped = resolve_methods(methods, sc.light.shape)
    names = [n for n in names if n != REFERENCE]
    params_by_method = {k: dict(v) for k, v in (params_by_method or {}).items()}
    for m in params_by_method:
        if m != REFERENCE and m not in names and m not in skipped:
            raise SoftShadowsError(
                f"--set names method '{m}', which is not being compared (methods: {', '.join(names) or '(none)'})"
            )
    # validate every parameter before the long renders start
    resolved = {}
    for m in [REFERENCE] + names:
        given = dict(params_by_method.get(m, {}))
        if m == REFERENCE:
            given.setdefault("samples", gt_samples)
        resolved[m] = get_method(m).resolve_params(given)
    check_folder(out_dir, "output folder (compare -o)")  # before the long renders; created when written

    def say(msg):
        if verbose:
            print(msg, file=sys.stderr, flush=True)

    from ._warm import say_if_cold, start_warmup, stop_warmup

    t_start = time.perf_counter()
    say_if_cold()
    # a cold cache: a helper process compiles methods (slow frames, then costliest first) while
    # this one traces the ground truth and compiles from the front (softshadows._warm)
    helper = start_warmup(scene, sc.light.shape, width, height, names, resolved)
    try:
        gt, results, failed = _render_all(sc, names, resolved, width, height, seed, progress, verbose, say, helper)
    finally:
        stop_warmup(helper)
    timed_while_compiling = helper is not None
    return _finish(
        sc,
        skipped,
        resolved,
        gt,
        results,
        failed,
        width,
        height,
        out_dir,
        command,
        seed,
        t_start,
        timed_while_compiling,
    )


def _render_all(sc, names, resolved, width, height, seed, progress, verbose, say, helper=None):
    """Ground truth, then each method. With a warm-up ``helper`` (a cold cache), a method it has
    claimed (softshadows._warm.helper_order) is rendered once it has cached its kernels, so that no
    kernel is compiled by both processes: after the method this process has just rendered if the
    helper is done with it by then, else at the end, waiting for it; the results keep the order of
    ``names``."""
    from . import render

    say(
        f"{sc.name} ({sc.light.shape} light) {width}x{height}: ground truth, {resolved[REFERENCE]['samples']} samples ..."
    )
    gt = render(sc, REFERENCE, width, height, seed=seed, progress=progress, **resolved[REFERENCE])
    results, failed = {}, {}
    todo = list(names)  # not rendered yet
    later = []  # claimed by the helper, not cached yet when this process came to them
    while todo:
        m = todo.pop(0)
        if helper is not None and not helper.claim(m):
            later.append(m)  # the helper compiles it now
            continue
        _render_method(sc, m, resolved, width, height, seed, verbose, say, results, failed)
        # the helper's methods cached meanwhile (the slow-frame ones are claimed first): now, not at the end
        for x in [x for x in later + todo if helper is not None and helper.cached(x)]:
            (later if x in later else todo).remove(x)
            _render_method(sc, x, resolved, width, height, seed, verbose, say, results, failed)
    for m in later:
        helper.wait(m)
        _render_method(sc, m, resolved, width, height, seed, verbose, say, results, failed)
    results = {m: results[m] for m in names if m in results}
    failed = {m: failed[m] for m in names if m in failed}
    return gt, results, failed


def _render_method(sc, m, resolved, width, height, seed, verbose, say, results, failed):
    """Render method ``m`` into ``results`` (or its failure into ``failed``)."""
    from . import render

    say(f"  {m} ...")
    try:
        # one untimed frame at the real size first: some kernels only run (and compile, on a
        # cold cache) at full size, which would otherwise land in the reported time
        render(sc, m, width, height, seed=seed, **resolved[m])
        results[m] = render(sc, m, width, height, seed=seed, **resolved[m])
    except SoftShadowsError:
        raise
    except Exception as exc:
        failed[m] = f"{type(exc).__name__}: {exc}"
        print(f"softshadows: warning: method '{m}' failed: {failed[m]}", file=sys.stderr)
        if verbose:
            traceback.print_exc()


#: said in the report, metrics.json and the command's output when a warm-up helper compiled while
#: the frames were timed (a cold cache: softshadows._warm)
COMPILING_NOTE = (
    "first run: the frame times were measured while a second process compiled kernels on the other"
    " core(s), so they can be up to about twice the steady-state ones; run the command again for those"
)


def _finish(
    sc,
    skipped,
    resolved,
    gt,
    results,
    failed,
    width,
    height,
    out_dir,
    command,
    seed,
    t_start,
    timed_while_compiling=False,
):
    from .methods import get_method
    from .metrics import compute_metrics, receiver_pixels, signed_error_map
    from .report import colorbar_png, error_heatmaps, error_limit, error_rgb, grid_image, machine_info, write_html
    from .shading import to_srgb8, visibility_to_rgb

    # metrics and images
    # methods that by design shade only receivers: also over receiver pixels (metrics["receivers"])
    metrics, errors = {}, {}
    recv = None
    for m, r in results.items():
        metrics[m] = compute_metrics(r.visibility, gt.visibility, r.image, gt.image)
        if get_method(m).receivers_only:
            recv = receiver_pixels(sc, width, height) if recv is None else recv
            metrics[m]["receivers"] = compute_metrics(r.visibility, gt.visibility, r.image, gt.image, mask=recv)
        errors[m] = signed_error_map(r.visibility, gt.visibility)
    limit = error_limit(list(errors.values()))
    files = []

    def out(name):
        p = os.path.join(out_dir, name)
        files.append(p)
        return p

    def entry(name, r, err):
        img8 = to_srgb8(r.image)
        v8 = to_srgb8(visibility_to_rgb(r.visibility))
        img_png, v_png = _png_bytes(img8), _png_bytes(v8)
        _write(out(f"{name}.png"), img_png)
        _write(out(f"{name}_V.png"), v_png)
        e_png = e_raw = None
        if err is not None:
            e_png = heatmaps[name]
            files.append(os.path.join(out_dir, f"{name}_error.png"))
            e_raw = _png_bytes(error_rgb(err, limit))
        return {
            "name": name,
            "params": r.params,
            "timings": r.timings,
            "stats": jsonable(r.stats),
            "images": {"image": img_png, "v": v_png, "error": e_png, "error_raw": e_raw},
            "img8": img8,
            "v8": v8,
        }

    # the error maps' figures, drawn on one figure (report.error_heatmaps), written as they are drawn
    heat_paths = [os.path.join(out_dir, f"{m}_error.png") for m in results]
    titles = [f"{m}: V - V_ref" for m in results]
    heatmaps = dict(zip(results, error_heatmaps(list(errors.values()), limit, heat_paths, titles), strict=True))
    ref_entry = entry(REFERENCE, gt, None)
    entries = []
    for m, r in results.items():
        e = entry(m, r, errors[m])
        meth = get_method(m)
        e.update(metrics=metrics[m], summary=meth.summary, paper=meth.paper, receivers_only=meth.receivers_only)
        entries.append(e)
    gmeth = get_method(REFERENCE)
    ref_entry.update(summary=gmeth.summary, paper=gmeth.paper)

    rows = [
        {
            "label": REFERENCE,
            "image": ref_entry["img8"],
            "v": ref_entry["v8"],
            "error": None,
            "caption": f"{gt.timings['total'] * 1e3:.0f} ms, {resolved[REFERENCE]['samples']} samples",
        }
    ]
    for e in entries:
        mt = e["metrics"]
        rows.append(
            {
                "label": e["name"],
                "image": e["img8"],
                "v": e["v8"],
                "error": errors[e["name"]],
                "caption": f"{e['timings']['total'] * 1e3:.0f} ms",
                "error_caption": f"MAE {mt['mae']:.4f}  ssm {mt['ssm_error']:.4f}  FLIP {mt.get('flip', float('nan')):.3f}"
                + (f"  (receivers: MAE {mt['receivers']['mae']:.4f})" if "receivers" in mt else ""),
            }
        )
    grid_png = grid_image(rows, limit, out("grid.png"), title=f"{sc.name}, {sc.light.shape} light, {width}x{height}")

    notes = [f"skipped {m}: {why}" for m, why in skipped.items()]
    if timed_while_compiling:
        notes.append(COMPILING_NOTE)
    info = scene_info(sc, width, height)
    machine = machine_info()
    doc = {
        "scene": info,
        "reference": {"method": REFERENCE, "params": gt.params, "timings": gt.timings, "stats": jsonable(gt.stats)},
        "methods": {
            e["name"]: {"metrics": e["metrics"], "timings": e["timings"], "params": e["params"], "stats": e["stats"]}
            for e in entries
        },
        "skipped": skipped,
        "failed": failed,
        "error_limit": limit,
        "machine": machine,
        "seed": seed,
        "timed_while_compiling": timed_while_compiling,
    }
    mpath = out("metrics.json")
    write_json(mpath, jsonable(doc))
    ctx = {
        "title": f"softshadows: {sc.name} ({sc.light.shape} light), {len(entries)} method(s) vs ground truth",
        "scene": info,
        "reference": ref_entry,
        "methods": entries,
        "grid": grid_png,
        "notes": notes,
        "failed": failed,
        "error_limit": limit,
        "machine": machine,
        "command": command,
        "colorbar": colorbar_png(limit),
        "viewer": _viewer_payload(gt, results, ref_entry, entries, limit),
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    report = write_html(out("report.html"), ctx)
    return {
        "out_dir": os.path.abspath(out_dir),
        "report": os.path.abspath(report),
        "files": [os.path.abspath(f) for f in files],
        "metrics": metrics,
        "timings": {REFERENCE: gt.timings, **{m: r.timings for m, r in results.items()}},
        "params": {REFERENCE: gt.params, **{m: r.params for m, r in results.items()}},
        "stats": {m: jsonable(r.stats) for m, r in results.items()},
        "skipped": skipped,
        "failed": failed,
        "error_limit": limit,
        "wall_s": time.perf_counter() - t_start,
        "timed_while_compiling": timed_while_compiling,
    }


def _viewer_payload(gt, results, ref_entry, entries, limit) -> dict:
    """The report viewer's data (report/viewer.py): reference first, then each method."""
    from .report.viewer import viewer_payload

    items = [{"name": REFERENCE, "v": gt.visibility, "image": ref_entry["images"]["image"], "caption": "reference"}]
    for e in entries:
        mt, ms = e["metrics"], e["timings"].get("total", float("nan")) * 1e3
        cap = f"MAE {mt['mae']:.4f}, {ms:.1f} ms"
        items.append(
            {"name": e["name"], "v": results[e["name"]].visibility, "image": e["images"]["image"], "caption": cap}
        )
    return viewer_payload(items, limit)


# ---- command line -----------------------------------------------------------------------------
def _cmd_compare(args) -> int:
    w, h = parse_size(args.size)
    sets = parse_method_sets(args.set)
    argv = ["softshadows", "compare"] + list(getattr(args, "_argv", []) or [])
    t0 = time.perf_counter()
    res = compare(
        args.scene,
        args.methods,
        w,
        h,
        args.output,
        sets,
        args.samples,
        light=args.light,
        seed=args.seed,
        progress=not args.quiet,
        verbose=not args.quiet,
        command=" ".join(argv) if len(argv) > 2 else None,
    )
    if not args.quiet:
        print(f"{'method':<30}{'MAE':>9}{'ssm':>9}{'bias':>9}{'FLIP':>8}{'ms':>10}")
        for m, mt in res["metrics"].items():
            rows = [(m, mt)]
            if "receivers" in mt:  # a receivers-only method: all surfaces, then receiver pixels only
                rows = [(m + " (all surfaces)", mt), (m + " (receivers)", mt["receivers"])]
            for label, x in rows:
                print(
                    f"{label:<30}{x['mae']:9.4f}{x['ssm_error']:9.4f}{x['bias']:9.4f}{x.get('flip', float('nan')):8.4f}"
                    f"{res['timings'][m]['total'] * 1e3:10.1f}"
                )
        for m, why in res["skipped"].items():
            print(f"skipped {m}: {why}")
        if res["timed_while_compiling"]:
            print(f"note: {COMPILING_NOTE}")
        print(f"done in {time.perf_counter() - t0:.1f} s")
    print(f"report: {res['report']}")
    return 1 if res["failed"] else 0


def register_cli(subparsers) -> None:
    p = subparsers.add_parser(
        "compare",
        help="ground truth + methods side by side: images, error maps, metrics, report.html",
        description="Render ground truth once and each method; write images, signed-error heat maps, "
        "grid.png, metrics.json and a self-contained report.html.",
    )
    p.add_argument(
        "scene",
        nargs="?",
        default=DEFAULT_SCENE,
        help=f"built-in name, TOML scene or mesh file (default {DEFAULT_SCENE})",
    )
    p.add_argument("--methods", default="all", help="'all' (default) or a comma-separated list")
    p.add_argument("--size", default=f"{DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]}", help="WxH (default %(default)s)")
    p.add_argument("--light", choices=("rect", "sphere"), default=None, help="swap in this light shape")
    p.add_argument("-o", "--output", default=DEFAULT_OUT, help="output directory (default %(default)s)")
    p.add_argument("--set", action="append", metavar="METHOD.KEY=VALUE", help="method parameter (repeatable)")
    p.add_argument(
        "--samples", type=int, default=DEFAULT_GT_SAMPLES, help="ground-truth light samples per pixel (N x N)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=_cmd_compare)
