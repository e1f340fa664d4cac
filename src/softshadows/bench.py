"""``bench``: frame times per method and phase, repeated after warm-up; parameter sweeps.

    softshadows bench [SCENE] --methods all|a,b,c --sizes 256,512,1024 [--repeats N] [--warmup N]
                      [--light rect|sphere] [--set method.key=value ...] [--json out.json]
    softshadows bench [SCENE] --sweep light-size|occluder-height|resolution|map-size|triangles
                      [--values v1,v2,...] --methods ... --size WxH --out plot.png [--json out.json]

Timing protocol (:func:`bench`): in one process, for each image size, every method first renders
once through :func:`softshadows.render` (which JIT-compiles on a tiny frame) plus ``warmup``
untimed frames at the measured size; then ``repeats`` rounds, each rendering every method once
(round-robin, so slow drifts of the machine hit all methods alike). Per phase we report the
median, min, max and the quartiles. ``hard`` is always measured in the same run (added if not
asked for), and each method gets ``ratio_to_hard`` = median total / hard's median total, and
``ratio_to_hard_method`` for the method's own phases only (total minus the shared
``eye_gbuffer`` and ``shading``). ``all`` excludes ``ground-truth`` (name it to time it).

Sweeps (:func:`sweep`, also the Python API for benchmark scripts) render ground truth and each
method for every value and plot frame time (median of ``repeats`` frames after warm-up, the
methods rendered round-robin as above, min-max band) and error against ground truth (``ssm_error`` by default: mean |dV| over umbra + penumbra,
Atty et al. 2006) against the parameter:

* ``light-size`` — value f scales the light (``light.scaled(f)``: rect edges or sphere radius x f);
* ``occluder-height`` — value dy (world units) moves every occluder-role mesh up by dy (new Mesh
  objects; the light stays); rejected if an occluder would reach the light's height;
* ``resolution`` — value N is the image width (height keeps the aspect of ``size``); methods'
  own map sizes stay at their parameters;
* ``map-size`` — value N is given to every method parameter named ``map_size`` or ending in
  ``_map_size`` / ``_resolution`` (shadow maps, occlusion textures ...); methods without one
  are rendered with their defaults (a flat line) and listed in ``notes``;
* ``triangles`` — value f multiplies the occluders' triangle count: f > 1 subdivides every
  occluder mesh (trimesh midpoint subdivision, x4 per level, until >= f x the original count;
  the shape does not change, only the cost), f < 1 simplifies it by quadric decimation
  (``fast_simplification``, through trimesh; the shape changes); the x axis is the actual count.
  With the scene ``icosphere`` the values are subdivision levels L of the triangle-throughput
  scene (``scene.builtin.icosphere``: 20 x 4^L + 2 triangles; default 4, 6, 8: 5 k, 82 k, 1.3 M),
  ``hard`` is always timed, ground truth too (``--samples`` spp, the reference), and so is the
  same ``hard`` frame in OpenGL on Mesa's llvmpipe where the optional ``peer`` extra can make a
  GL context (:mod:`softshadows.peer`; else the column says n/a and why); :func:`triangles_table`
  prints the table of issue 15 (ms and x hard per method, llvmpipe's ms and V agreement).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from .api import check_seed, check_size
from .compare import REFERENCE, jsonable, load, parse_method_sets, parse_size, resolve_methods
from .errors import SoftShadowsError
from .io import IMAGE_EXTS, JSON_EXTS, check_outputs, write_json
from .peer import AGREEMENT_TOL, PEERS, agreement, make_peer, peer_params

SHARED_PHASES = ("eye_gbuffer", "shading")
SWEEP_KINDS = ("light-size", "occluder-height", "resolution", "map-size", "triangles")
DEFAULT_SWEEP_VALUES = {
    "light-size": [0.25, 0.5, 1.0, 1.5, 2.0],
    "occluder-height": [0.0, 0.2, 0.4, 0.6, 0.8],
    "resolution": [128, 256, 384, 512],
    "map-size": [128, 256, 512, 1024, 2048],
    "triangles": [0.25, 0.5, 1.0, 4.0, 16.0],
}
#: the triangles sweep's scene of icosphere levels (``scene.builtin.icosphere``) and its default levels
ICOSPHERE = "icosphere"
ICOSPHERE_LEVELS = [4, 6, 8]


def summary_stats(x) -> dict:
    """{median, min, max, q1, q3, n} of the values ``x`` (quartiles: NumPy's linear percentiles)."""
    a = np.asarray(x, float)
    q1, med, q3 = np.percentile(a, [25, 50, 75])
    return {
        "median": float(med),
        "min": float(a.min()),
        "max": float(a.max()),
        "q1": float(q1),
        "q3": float(q3),
        "n": int(a.size),
    }


def _sizes(sizes) -> list[tuple[int, int]]:
    if isinstance(sizes, (int, np.integer)):
        sizes = [int(sizes)]
    if isinstance(sizes, str):
        sizes = [s for s in sizes.split(",") if s.strip()]
    out = []
    for s in sizes:
        if isinstance(s, (tuple, list)):
            w, h = int(s[0]), int(s[1])
        else:
            w, h = parse_size(str(s).strip())
        check_size(w, h)  # every size (and its memory estimate) checked before the first frame
        out.append((w, h))
    if not out:
        raise SoftShadowsError("--sizes is empty; give e.g. 256,512,1024 or 640x480")
    return out


def _method_time(timings: dict) -> float:
    return timings["total"] - sum(timings.get(p, 0.0) for p in SHARED_PHASES)


def _resolve_all(names, params_by_method):
    from .methods import get_method

    params_by_method = params_by_method or {}
    for m in params_by_method:
        if m not in names:
            raise SoftShadowsError(f"--set names method '{m}', which is not being run (methods: {', '.join(names)})")
    return {m: get_method(m).resolve_params(params_by_method.get(m, {})) for m in names}


def bench(
    scene="bunny",
    methods="all",
    sizes=(512,),
    repeats: int = 5,
    warmup: int = 1,
    *,
    params_by_method: dict | None = None,
    light: str | None = None,
    seed: int = 0,
    verbose: bool = False,
) -> dict:
    """Time ``methods`` on ``scene`` at each of ``sizes`` (ints for N x N, 'WxH' or (w, h)).

    Returns ``{"scene", "light", "machine", "repeats", "warmup", "skipped", "results": [{"size",
    "method", "params", "timings": {phase: {median, min, max, q1, q3, n}}, "method_time",
    "ratio_to_hard", "ratio_to_hard_method", "ratio_to_hard_paired"}]}`` (seconds).
    ``ratio_to_hard`` is the ratio of the medians; ``ratio_to_hard_paired`` the statistics of the
    per-round ratios (each frame against ``hard``'s frame of the same round, rendered a few
    milliseconds apart, so that the host's slower and faster stretches cancel), {median, min, max,
    q1, q3, n}."""
    from . import render
    from .report import machine_info

    if int(repeats) < 1:
        raise SoftShadowsError(f"--repeats must be >= 1, got {repeats}")
    if int(warmup) < 0:
        raise SoftShadowsError(f"--warmup must be >= 0, got {warmup}")
    sc = load(scene, light)
    names, skipped = resolve_methods(methods, sc.light.shape)
    if "hard" not in names:
        names = ["hard"] + names
    resolved = _resolve_all(names, params_by_method)
    results = []
    for w, h in _sizes(sizes):
        samples: dict = {m: [] for m in names}
        for m in names:
            if verbose:
                print(f"  warm-up {m} {w}x{h}", file=sys.stderr, flush=True)
            for _ in range(int(warmup)):
                render(sc, m, w, h, seed=seed, **resolved[m])
        for _r in range(int(repeats)):
            for m in names:
                samples[m].append(render(sc, m, w, h, seed=seed, **resolved[m]).timings)
        hard_total = float(np.median([t["total"] for t in samples["hard"]]))
        hard_method = float(np.median([_method_time(t) for t in samples["hard"]]))
        for m in names:
            phases = []
            for t in samples[m]:
                for k in t:
                    if k not in phases:
                        phases.append(k)
            tim = {p: summary_stats([t.get(p, 0.0) for t in samples[m]]) for p in phases}
            mt = summary_stats([_method_time(t) for t in samples[m]])
            paired = summary_stats(
                [t["total"] / th["total"] for t, th in zip(samples[m], samples["hard"], strict=True)]
            )
            results.append(
                {
                    "size": [w, h],
                    "method": m,
                    "params": resolved[m],
                    "timings": tim,
                    "method_time": mt,
                    "ratio_to_hard": tim["total"]["median"] / hard_total if hard_total > 0 else float("nan"),
                    "ratio_to_hard_method": mt["median"] / hard_method if hard_method > 0 else float("nan"),
                    "ratio_to_hard_paired": paired,
                }
            )
    return {
        "scene": sc.name,
        "light": sc.light.shape,
        "repeats": int(repeats),
        "warmup": int(warmup),
        "seed": seed,
        "skipped": skipped,
        "machine": machine_info(),
        "results": results,
    }


def format_table(res: dict) -> str:
    """The printed table: one row per (size, method), milliseconds."""
    lines = [
        f"{res['scene']} ({res['light']} light), {res['repeats']} repeats after {res['warmup']} warm-up frame(s); "
        f"times in ms: median [min-max]; x hard = ratio of medians (whole frame / method phases only); "
        f"x round = median of the per-round ratios (each frame against hard's frame of the same round)"
    ]
    lines.append(
        f"{'size':>10}  {'method':<20}{'total':>10} {'[min-max]':>17} {'x hard':>7} {'x hard*':>8} {'x round':>8}"
        f"  phases (median)"
    )
    for r in res["results"]:
        t = r["timings"]
        ph = "  ".join(f"{k}={v['median'] * 1e3:.1f}" for k, v in t.items() if k != "total")
        lines.append(
            f"{r['size'][0]:>5}x{r['size'][1]:<4}  {r['method']:<20}{t['total']['median'] * 1e3:10.1f} "
            f"{'[' + format(t['total']['min'] * 1e3, '.1f') + '-' + format(t['total']['max'] * 1e3, '.1f') + ']':>17} "
            f"{r['ratio_to_hard']:7.2f} {r['ratio_to_hard_method']:8.2f} {r['ratio_to_hard_paired']['median']:8.2f}  {ph}"
        )
    for m, why in res.get("skipped", {}).items():
        lines.append(f"skipped {m}: {why}")
    return "\n".join(lines)


# ---- sweeps -----------------------------------------------------------------------------------
def _map_params(method) -> list[str]:
    return [
        p.name
        for p in method.params
        if p.name == "map_size" or p.name.endswith("_map_size") or p.name.endswith("_resolution")
    ]


def translate_occluders(scene, dy: float):
    """A copy of ``scene`` whose occluder-role meshes are moved up (+y) by ``dy``."""
    from .scene.types import Mesh, Scene

    if not any(m.role == "occluder" for m in scene.meshes):
        raise SoftShadowsError(
            f"scene '{scene.name}' has no mesh with role 'occluder' to move "
            "(occluder-height needs separate occluder and receiver meshes)"
        )
    meshes = []
    top = -np.inf
    for m in scene.meshes:
        if m.role == "occluder":
            v = m.vertices.copy()
            v[:, 1] += dy
            top = max(top, float(v[:, 1].max()))
            m = Mesh(v, m.faces, m.albedo, m.role, m.name)
        meshes.append(m)
    if top >= scene.light.center[1]:
        raise SoftShadowsError(
            f"occluder-height {dy:g} lifts the occluders to y={top:.3g}, at or above "
            f"the light (y={scene.light.center[1]:.3g})"
        )
    return Scene(meshes, scene.light, scene.camera, scene.name)


def retriangulate_occluders(scene, factor: float):
    """A copy of ``scene`` whose occluder-role meshes have about ``factor`` x their triangles."""
    import trimesh

    from .scene.types import Mesh, Scene

    if factor <= 0:
        raise SoftShadowsError(f"triangles factor must be > 0, got {factor}")
    meshes = []
    for m in scene.meshes:
        if m.role in ("occluder", "both") and abs(factor - 1.0) > 1e-9:
            target = max(4, int(round(len(m.faces) * factor)))
            v, f = m.vertices, m.faces
            if factor > 1:
                while len(f) < target:
                    v, f = trimesh.remesh.subdivide(v, f)
            elif target < len(f):
                tm = trimesh.Trimesh(v, f, process=False)
                try:
                    dec = tm.simplify_quadric_decimation(face_count=target)
                except (ImportError, ModuleNotFoundError) as exc:
                    raise SoftShadowsError(
                        f"triangles < 1 needs quadric decimation: pip install fast-simplification ({exc})"
                    ) from None
                except ValueError as exc:
                    raise SoftShadowsError(f"cannot decimate mesh '{m.name}' to {target} triangles: {exc}") from None
                v, f = np.asarray(dec.vertices), np.asarray(dec.faces)
            m = Mesh(v, f, m.albedo, m.role, m.name)
        meshes.append(m)
    return Scene(meshes, scene.light, scene.camera, scene.name)


def sweep(
    scene_name,
    kind: str,
    values=None,
    methods="pcss",
    size=(256, 256),
    params_by_method: dict | None = None,
    out_png=None,
    light: str | None = None,
    *,
    gt_samples: int = 256,
    repeats: int = 3,
    seed: int = 0,
    error_key: str = "ssm_error",
    verbose: bool = False,
) -> dict:
    """Sweep ``kind`` over ``values`` (None: :data:`DEFAULT_SWEEP_VALUES`) on ``scene_name`` (a
    name, file or Scene) for ``methods``; write the plot to ``out_png`` (if given).

    Returns ``{"scene", "kind", "values", "x", "x_label", "size", "gt_samples", "notes", "png",
    "methods": {m: {"time_ms", "time_min_ms", "time_max_ms", "mae", "ssm_error", "rmse", "bias",
    "metrics": [full dicts]}}}``.
    """
    from . import render
    from .methods import get_method
    from .metrics import compute_metrics
    from .report import sweep_plot

    if kind not in SWEEP_KINDS:
        raise SoftShadowsError(f"unknown sweep '{kind}'; valid: {', '.join(SWEEP_KINDS)}")
    ico = isinstance(scene_name, str) and scene_name == ICOSPHERE
    if ico and kind != "triangles":
        raise SoftShadowsError(f"the '{ICOSPHERE}' scene is for --sweep triangles (its values are subdivision levels)")
    if ico:
        from .scene.builtin import icosphere

        vals = list(ICOSPHERE_LEVELS if values is None else values)
        for v in vals:
            if float(v) != int(float(v)) or not 0 <= int(float(v)) <= 10:
                raise SoftShadowsError(f"icosphere levels must be integers in 0..10, got {v}")
        vals = [int(float(v)) for v in vals]
        base = icosphere(vals[0] if vals else 0, light or "rect")
    else:
        base = load(scene_name, light)
        vals = list(DEFAULT_SWEEP_VALUES[kind] if values is None else values)
    w0, h0 = _sizes([size])[0]
    if not vals:
        raise SoftShadowsError("--values is empty")
    names, skipped = resolve_methods(methods, base.light.shape)
    names = [n for n in names if n != REFERENCE]
    if ico and "hard" not in names:
        names.insert(0, "hard")  # the x-hard columns and the llvmpipe peers need it
    if not names:
        raise SoftShadowsError("no method to sweep (all were skipped for this light shape)")
    base_params = _resolve_all(names, params_by_method)
    notes = [f"skipped {m}: {why}" for m, why in skipped.items()]
    if kind == "map-size":
        for m in names:
            if not _map_params(get_method(m)):
                notes.append(f"{m} has no map-size parameter: rendered with its defaults")
    out = {m: {"time_ms": [], "time_min_ms": [], "time_max_ms": [], "metrics": []} for m in names}
    xs = []
    ref_ms = []  # ground truth's frame time (icosphere sweep)
    # the GL peers: hard's frame always, pcss's where pcss is swept (softshadows.peer.PEERS)
    peers = {
        m: {"label": f"llvmpipe `{m}`", "time_ms": [], "disagree": [], "cover": [], "renderer": None, "reason": None}
        for m in names
        if m in PEERS
    }
    for val in vals:
        sc, w, h = base, w0, h0
        params = {m: dict(p) for m, p in base_params.items()}
        x = float(val)
        if kind == "light-size":
            if float(val) <= 0:
                raise SoftShadowsError(f"light-size factor must be > 0, got {val}")
            sc = base.with_light(base.light.scaled(float(val)))
        elif kind == "occluder-height":
            sc = translate_occluders(base, float(val))
        elif kind == "resolution":
            w = int(val)
            h = max(1, int(round(w * h0 / w0)))
        elif kind == "map-size":
            for m in names:
                for pn in _map_params(get_method(m)):
                    params[m][pn] = get_method(m).resolve_params({pn: int(val)})[pn]
        elif kind == "triangles" and ico:
            sc = base if int(val) == vals[0] else icosphere(int(val), light or "rect")
            x = float(len(sc.flat.faces))
        elif kind == "triangles":
            sc = retriangulate_occluders(base, float(val))
            x = float(sc.flat.occluder.sum())
        xs.append(x)
        if verbose:
            print(f"  {kind}={val}: ground truth ...", file=sys.stderr, flush=True)
        gt = render(sc, REFERENCE, w, h, seed=seed, samples=gt_samples)
        if ico:  # ground truth is a column of the table: timed like the methods
            ref_ms.append(_median_ms(render, sc, REFERENCE, w, h, seed, {"samples": gt_samples}, repeats)[0])
        for m in names:
            render(sc, m, w, h, seed=seed, **params[m])  # warm-up at this size (JIT, caches)
        # interleaved: each round renders every method once, so load changes hit them alike
        times = {m: [] for m in names}
        last = {}
        for _ in range(max(1, int(repeats))):
            for m in names:
                last[m] = render(sc, m, w, h, seed=seed, **params[m])
                times[m].append(last[m].timings["total"] * 1e3)
        if ico:
            for m, peer in peers.items():
                _time_peer(peer, m, sc, w, h, params[m], last[m].visibility, repeats)
        for m in names:
            ts, res = times[m], last[m]
            met = compute_metrics(res.visibility, gt.visibility)
            d = out[m]
            d["time_ms"].append(float(np.median(ts)))
            d["time_min_ms"].append(float(np.min(ts)))
            d["time_max_ms"].append(float(np.max(ts)))
            d["metrics"].append(met)
    for d in out.values():
        for k in ("mae", "rmse", "bias", "ssm_error", "mae_penumbra", "mae_umbra", "mae_lit"):
            d[k] = [mt[k] for mt in d["metrics"]]
    x_label = {
        "light-size": "light size factor (x the scene's light)",
        "occluder-height": "occluder lift dy (world units)",
        "resolution": f"image width (height = width x {h0}/{w0})",
        "map-size": "map size (texels per side)",
        "triangles": "occluder triangles",
    }[kind]
    data = {
        "scene": base.name,
        "light": base.light.shape,
        "kind": kind,
        "values": vals,
        "x": xs,
        "x_label": x_label,
        "size": [w0, h0],
        "gt_samples": gt_samples,
        "repeats": int(repeats),
        "error_key": error_key,
        "notes": notes,
        "methods": out,
        "log_x": kind in ("map-size", "triangles", "resolution"),
    }
    if ico:
        data["scene"] = ICOSPHERE  # not the first level's name
        data["x_label"] = "triangles (icosphere over a ground quad)"
        data["reference_time_ms"] = ref_ms
        data["peers"] = peers
    if out_png:
        sweep_plot(data, out_png, error_key=error_key)
        data["png"] = str(out_png)
    return data


def _median_ms(render, sc, method, w, h, seed, params, repeats) -> tuple[float, object]:
    """(median ms of ``repeats`` frames, the last result) of ``method`` after one warm-up frame."""
    render(sc, method, w, h, seed=seed, **params)
    ts, res = [], None
    for _ in range(max(1, int(repeats))):
        res = render(sc, method, w, h, seed=seed, **params)
        ts.append(res.timings["total"] * 1e3)
    return float(np.median(ts)), res


def _time_peer(peer: dict, method: str, sc, w, h, params: dict, v_ours, repeats) -> None:
    """Append to ``peer`` the median ms of ``method``'s frame in OpenGL on llvmpipe (after one
    warm-up frame: shader compile) and the agreement of its V with ours (``peer.AGREEMENT_TOL``);
    NaN (and ``peer["reason"]``) where no GL context can be made or the GL frame does not implement
    the parameters."""
    gl, why = None, peer["reason"]
    if why is None:
        try:
            extra = peer_params(method, params)
        except ValueError as exc:
            why = str(exc)
        else:
            gl, why = make_peer(
                sc, w, h, params["map_size"], params["bias"], params["slope_bias"], method=method, **extra
            )
    if gl is None:
        peer["reason"] = why
        for k in ("time_ms", "disagree", "cover"):
            peer[k].append(float("nan"))
        return
    peer["renderer"] = gl.renderer
    v = gl.frame()
    ts = []
    for _ in range(max(1, int(repeats))):
        t0 = time.perf_counter()
        gl.frame()
        ts.append((time.perf_counter() - t0) * 1e3)
    disagree, cover, _n = agreement(v_ours, v, AGREEMENT_TOL[method])
    peer["time_ms"].append(float(np.median(ts)))
    peer["disagree"].append(disagree)
    peer["cover"].append(cover)
    gl.release()


def triangles_table(data: dict) -> str:
    """The table of issue 15 from an icosphere triangles sweep: per level the triangle count, each
    method's median ms (x hard's), ground truth's and the llvmpipe peers' frames (x our frame of the
    same method), or n/a and why."""
    ms = data["methods"]
    hard = ms["hard"]["time_ms"]
    peers = data.get("peers") or {}
    ref = data.get("reference_time_ms") or []
    cols = (
        list(ms) + ([f"{REFERENCE} ({data['gt_samples']} spp)"] if ref else []) + [p["label"] for p in peers.values()]
    )
    lines = ["| triangles | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for i, x in enumerate(data["x"]):
        times = [(m, d["time_ms"][i]) for m, d in ms.items()] + ([(REFERENCE, ref[i])] if ref else [])
        cells = [f"{t:.0f}" if m == "hard" else f"{t:.0f} ({t / hard[i]:.2f}x)" for m, t in times]
        for m, peer in peers.items():
            pt = (peer.get("time_ms") or [float("nan")] * len(data["x"]))[i]
            cells.append("n/a" if not np.isfinite(pt) else f"{pt:.0f} ({pt / ms[m]['time_ms'][i]:.2f}x)")
        lines.append(f"| {int(x):,} | " + " | ".join(cells) + " |")
    lines.append(
        f"median ms of {data.get('repeats', '?')} frames at {data['size'][0]}x{data['size'][1]}, (x hard); "
        "llvmpipe: (x our frame of the same method)"
    )
    for m, peer in peers.items():
        if peer.get("reason"):
            lines.append(f"llvmpipe `{m}`: n/a: {peer['reason']}")
        elif peer.get("time_ms"):
            dis = max(peer["disagree"])
            tol = AGREEMENT_TOL[m]
            how = "differs from" if tol == 0 else f"is more than {tol} from"
            lines.append(
                f"llvmpipe `{m}` ({peer.get('renderer')}): its V {how} {m}'s on at most {100 * dis:.3f}% of pixels"
            )
    return "\n".join(lines)


# ---- command line -----------------------------------------------------------------------------
def _float_list(text, what) -> list[float]:
    try:
        return [float(s) for s in str(text).split(",") if s.strip()]
    except ValueError:
        raise SoftShadowsError(f"{what} must be comma-separated numbers, got '{text}'") from None


def _cmd_bench(args) -> int:
    sets = parse_method_sets(args.set)
    check_seed(args.seed)
    if args.sweep:
        values = _float_list(args.values, "--values") if args.values else None
        if values is not None and args.sweep in ("resolution", "map-size"):
            values = [int(v) for v in values]
        out_png = args.out or f"sweep-{args.sweep}.png"
        check_outputs([("--out", out_png, IMAGE_EXTS), ("--json", args.json, JSON_EXTS)])
    else:
        check_outputs([("--json", args.json, JSON_EXTS)])
    if args.sweep:
        methods = args.methods if args.methods != "all" else "all"
        data = sweep(
            args.scene,
            args.sweep,
            values,
            methods,
            parse_size(args.size),
            sets,
            out_png,
            light=args.light,
            gt_samples=args.samples,
            repeats=args.repeats,
            seed=args.seed,
            verbose=not args.quiet,
        )
        print(f"{data['scene']} {data['kind']} sweep, {data['size'][0]}x{data['size'][1]}:")
        print(f"{'x':>12}  " + "".join(f"{m[:18]:>20}" for m in data["methods"]) + "   (ms | ssm_error)")
        for i, x in enumerate(data["x"]):
            row = "".join(f"{d['time_ms'][i]:9.1f} | {d['ssm_error'][i]:7.4f}  " for d in data["methods"].values())
            print(f"{x:12.4g}  {row}")
        for n in data["notes"]:
            print(n)
        if "peers" in data:
            print()
            print(triangles_table(data))
        if args.json:
            write_json(args.json, jsonable(data))
            print(f"wrote {args.json}")
        print(f"plot: {out_png}")
        return 0
    res = bench(
        args.scene,
        args.methods,
        _sizes(args.sizes),
        args.repeats,
        args.warmup,
        params_by_method=sets,
        light=args.light,
        seed=args.seed,
        verbose=not args.quiet,
    )
    print(format_table(res))
    if args.json:
        write_json(args.json, jsonable(res))
        print(f"wrote {args.json}")
    return 0


def register_cli(subparsers) -> None:
    p = subparsers.add_parser(
        "bench",
        help="time methods per phase (median, spread, ratio to hard); --sweep plots time and error",
        description="Time each method after warm-up, repeated, per phase, with the ratio to 'hard' "
        "measured in the same run; or sweep a parameter and plot time and error vs ground truth.",
    )
    p.add_argument("scene", nargs="?", default="bunny", help="built-in name, TOML scene or mesh file (default bunny)")
    p.add_argument("--methods", default="all", help="'all' (every method but ground-truth) or a comma-separated list")
    p.add_argument("--sizes", default="512", help="comma-separated N (N x N) or WxH (default %(default)s)")
    p.add_argument("--repeats", type=int, default=5, help="timed frames per method and size (default %(default)s)")
    p.add_argument("--warmup", type=int, default=1, help="untimed frames per method and size (default %(default)s)")
    p.add_argument("--light", choices=("rect", "sphere"), default=None, help="swap in this light shape")
    p.add_argument("--set", action="append", metavar="METHOD.KEY=VALUE", help="method parameter (repeatable)")
    p.add_argument("--json", help="write the results as JSON")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sweep", choices=SWEEP_KINDS, help="sweep a parameter instead of timing sizes")
    p.add_argument("--values", help="sweep values, comma-separated (defaults per kind)")
    p.add_argument("--size", default="256x256", help="image size of a sweep (default %(default)s)")
    p.add_argument("--samples", type=int, default=256, help="ground-truth samples of a sweep (default %(default)s)")
    p.add_argument("--out", help="sweep plot PNG (default sweep-KIND.png)")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=_cmd_bench)
