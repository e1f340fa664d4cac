"""The ``softshadows`` command line.

    softshadows render [SCENE] --method M --size WxH --light rect|sphere --set key=value -o out.png [--exr out.exr]
    softshadows list
    softshadows compare ...   (softshadows.compare)
    softshadows bench ...     (softshadows.bench)
    softshadows pareto ...    (softshadows.pareto; render --method auto --budget-ms X uses its front)

Bad input prints one line ``softshadows: error: ...`` and exits with code 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from .errors import SoftShadowsError

DEFAULT_SCENE = "bunny"


def parse_size(text: str) -> tuple[int, int]:
    """'512x384' -> (512, 384); '256' -> (256, 256). Raises SoftShadowsError on bad input."""
    t = str(text).lower().strip()
    parts = t.split("x") if "x" in t else [t, t]
    try:
        if len(parts) != 2:
            raise ValueError
        w, h = int(parts[0]), int(parts[1])
    except ValueError:
        raise SoftShadowsError(f"--size must be WxH with positive integers (e.g. 512x512), got '{text}'") from None
    if w <= 0 or h <= 0:
        raise SoftShadowsError(f"--size must be positive, got '{text}'")
    if w > 16384 or h > 16384:
        raise SoftShadowsError(f"--size {text} is too large (max 16384 per side)")
    return w, h


def parse_sets(items: list[str] | None) -> dict[str, str]:
    """['key=value', ...] -> {key: value}; raises on a malformed item."""
    out: dict[str, str] = {}
    for it in items or []:
        if "=" not in it or not it.split("=", 1)[0].strip():
            raise SoftShadowsError(f"--set expects key=value, got '{it}'")
        k, v = it.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _cmd_render(args) -> int:
    import numpy as np

    from . import load_scene, render
    from .api import check_seed
    from .io import EXR_EXTS, IMAGE_EXTS, OutputGroup, check_outputs
    from .shading import save_exr, save_png, visibility_to_rgb

    w, h = parse_size(args.size)
    params = parse_sets(args.set)
    seed = check_seed(args.seed)
    scene = load_scene(args.scene, light=args.light)
    out = args.output or f"{scene.name}-{args.method}.png"
    # every output checked before rendering; all written together (temp files renamed at the end)
    check_outputs(
        [("-o/--output", out, IMAGE_EXTS), ("--exr", args.exr, EXR_EXTS), ("--v-png", args.v_png, IMAGE_EXTS)]
    )
    method = args.method
    if method == "auto":  # the least-error setting within --budget-ms on this machine (softshadows.pareto)
        method, params = _auto_method(scene, w, h, args.budget_ms, params, quiet=args.quiet)
    elif args.budget_ms is not None:
        raise SoftShadowsError("--budget-ms applies to --method auto only")
    res = render(scene, method, w, h, seed=seed, progress=not args.quiet, **params)
    with OutputGroup() as g:
        save_png(g.path(out), res.image)
        if args.exr:
            chans = {"V": res.visibility, "R": res.image[..., 0], "G": res.image[..., 1], "B": res.image[..., 2]}
            save_exr(g.path(args.exr), chans)
        if args.v_png:
            save_png(g.path(args.v_png), visibility_to_rgb(res.visibility))
    if not args.quiet:
        vmask = ~np.isnan(res.visibility)
        ms = "  ".join(f"{k}={v * 1e3:.1f}ms" for k, v in res.timings.items())
        print(
            f"{scene.name} ({scene.light.shape} light) {method} {w}x{h}: mean V={np.nanmean(res.visibility[vmask]) if vmask.any() else float('nan'):.3f}"
        )
        print(f"  {ms}")
        shown = {k: v for k, v in res.stats.items() if not k.startswith("_")}
        if shown:
            print("  stats: " + ", ".join(f"{k}={v}" for k, v in shown.items()))
        print(f"wrote {out}" + (f" and {args.exr}" if args.exr else ""))
    return 0


def _auto_method(scene, w, h, budget_ms, sets, quiet=False):
    from .pareto import auto_choice, describe

    if sets:
        raise SoftShadowsError("--set cannot be combined with --method auto (it picks the parameters)")
    method, params, point, fits, path = auto_choice(scene, w, h, budget_ms, progress=not quiet, verbose=not quiet)
    if not quiet:
        print(
            f"auto ({budget_ms:g} ms budget): {describe(point)}"
            + ("" if fits else " -- nothing fits the budget, the fastest setting")
            + f"; front: {path}"
        )
    return method, params


def _cmd_list(args) -> int:
    from .methods import methods
    from .scene.builtin import BUILTIN

    print("Built-in scenes (each with --light rect|sphere):")
    for name, entry in BUILTIN.items():
        desc = entry[0] if isinstance(entry, tuple) else getattr(entry, "description", "")
        print(f"  {name:<10} {desc}")
    print("\nMethods (parameters with defaults; set with --set key=value):")
    for name, m in methods().items():
        print(f"  {name:<20} [{'/'.join(m.light_shapes)}] {m.summary}")
        for p in m.params:
            print(f"      {p.describe():<32} {p.help}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="softshadows", description="Soft shadows from area lights: methods vs ground truth."
    )
    sub = ap.add_subparsers(dest="command")

    r = sub.add_parser("render", help="render one method on one scene")
    r.add_argument("scene", nargs="?", default=DEFAULT_SCENE, help="built-in name, TOML scene or mesh file")
    r.add_argument("--method", "-m", default="ground-truth", help="a method, or 'auto' (with --budget-ms)")
    r.add_argument(
        "--budget-ms",
        dest="budget_ms",
        type=float,
        default=None,
        help="with --method auto: the least-error method and settings within this frame time (softshadows pareto)",
    )
    r.add_argument("--size", default="512x512", help="WxH")
    r.add_argument("--light", choices=("rect", "sphere"), default=None, help="swap in this light shape")
    r.add_argument("--set", action="append", metavar="KEY=VALUE", help="method parameter (repeatable)")
    r.add_argument("--seed", type=int, default=0, help="random seed, an integer in [0, 2**63-1]")
    r.add_argument("-o", "--output", help="PNG path (default SCENE-METHOD.png)")
    r.add_argument("--exr", help="also write V and the linear image to this OpenEXR file")
    r.add_argument("--v-png", dest="v_png", help="also write V as a grey PNG")
    r.add_argument("-q", "--quiet", action="store_true")
    r.set_defaults(func=_cmd_render)

    ls = sub.add_parser("list", help="list built-in scenes, methods and their parameters")
    ls.set_defaults(func=_cmd_list)

    for modname in ("compare", "bench", "pareto"):
        try:
            mod = importlib.import_module(f"softshadows.{modname}")
        except ModuleNotFoundError as exc:
            if exc.name != f"softshadows.{modname}":
                raise
            continue
        if hasattr(mod, "register_cli"):
            mod.register_cli(sub)
    return ap


class _Parser(argparse.ArgumentParser):
    pass


def main(argv=None) -> int:
    from ._malloc import tune_malloc

    tune_malloc()  # the CLI owns the process: keep frame buffers in the heap (softshadows._malloc)
    # ... and its OpenMP threads: sleep at barriers instead of spinning. Spinning workers steal the
    # cores on a shared/loaded machine: every parallel kernel waits for a descheduled spinner
    # (bunny 512^2 on 2 loaded cores: hard 221 -> 105 ms; docs/results/speed-targets.md). Read when
    # the OpenMP runtime starts (the first parallel kernel), so set before anything runs; a value
    # the user set wins. Importing the library does not do this.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    ap = build_parser()
    # argparse errors (unknown option, bad choice) exit 2 with a usage line already
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        argv = ["compare"] if "compare" in ap._subparsers._group_actions[0].choices else ["--help"]
    args = ap.parse_args(argv)
    if not getattr(args, "func", None):
        ap.print_help()
        return 2
    with warnings.catch_warnings():
        warnings.simplefilter("default")  # each distinct warning once
        warnings.showwarning = lambda msg, cat, fn, ln, file=None, line=None: print(
            f"softshadows: warning: {msg}", file=sys.stderr
        )
        try:
            return int(args.func(args) or 0)
        except SoftShadowsError as exc:
            print(f"softshadows: error: {exc}", file=sys.stderr)
            return 2
        except FileNotFoundError as exc:
            print(f"softshadows: error: {exc.filename or exc}: file not found", file=sys.stderr)
            return 2
        except OSError as exc:
            where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
            print(f"softshadows: error: {where}{exc.strerror or ' '.join(str(exc).split())}", file=sys.stderr)
            return 2
        except MemoryError:
            print("softshadows: error: out of memory; use a smaller --size", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print("softshadows: interrupted", file=sys.stderr)
            return 130


if __name__ == "__main__":
    sys.exit(main())
