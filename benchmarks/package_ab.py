"""Whole frames of the working tree against the whole package at a base revision, interleaved in one
process after warm-up: for changes that reach every module at once (the rasterizer, the kernels'
threading), which ``frame_ab.py`` (method modules only) and ``hard_frame_ab.py`` (hard's own
modules) do not see. The base is ``git archive <base> src/softshadows`` imported under another
package name (its relative imports keep it self-contained; its JIT cache lives next to it, kept
between runs of the same base). Checks that V, the image and the stats are the same bit for bit,
apart from timings a method reports in them (keys ending in ``_s``),
and prints per method the median frame of each and the median of the per-round ratios new/base.

It is biased toward the working tree: with the same code on both sides (``--base HEAD`` on a clean
tree) it measured 0.88-0.91 for ``hard`` and 0.96 for ``pcss`` on 2026-12-03, whichever scene was
loaded first (0.96 for ``hard`` at one thread; the cause was not found). Run it both ways round:
here with ``--base OLD`` (r_new), then from a worktree of OLD with ``--base NEW`` (r_old); the
estimate of new/old is sqrt(r_new / r_old), the bias sqrt(r_new * r_old).

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/package_ab.py --base 6bf3dc4 \\
        --methods hard,pcss,layered-attenuation,irregular --light rect --reps 31
"""

from __future__ import annotations

import argparse
import importlib
import os
import shutil
import subprocess
import sys
import tempfile
import time


def base_package(rev: str):
    """The package at ``rev`` as module ``softshadows_base`` (extracted once per revision)."""
    sha = subprocess.run(["git", "rev-parse", rev], check=True, capture_output=True, text=True).stdout.strip()
    root = os.path.join(tempfile.gettempdir(), f"softshadows_base_{sha[:12]}")
    pkg = os.path.join(root, "softshadows_base")
    if not os.path.isdir(pkg):
        tmp = tempfile.mkdtemp(prefix="package_ab_")
        tar = subprocess.run(["git", "archive", sha, "src/softshadows"], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=tar, check=True)
        os.makedirs(root, exist_ok=True)
        shutil.move(os.path.join(tmp, "src", "softshadows"), pkg)
        shutil.rmtree(tmp)
    sys.path.insert(0, root)
    return importlib.import_module("softshadows_base")


def _untimed(stats: dict) -> dict:
    """The stats without the timings some methods report (keys ending in ``_s``, or with ``_s_`` before
    a variant's name: occlusion-textures' ``prefilter_s_<filter>``)."""
    return {k: v for k, v in stats.items() if not (k.endswith("_s") or "_s_" in k)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git revision of the base")
    ap.add_argument("--methods", default="hard,pcss")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--reps", type=int, default=21)
    a = ap.parse_args()
    import numpy as np

    import softshadows as new

    base = base_package(a.base)
    new.tune_malloc()  # a benchmark owns its process (softshadows._malloc)
    pkgs = {"new": new, "base": base}
    scenes = {k: pkgs[k].load_scene(a.scene, a.light) for k in pkgs}
    print(f"{a.scene} {a.light} {a.size}^2, new = working tree, base = {a.base}; {a.reps} rounds after warm-up")
    for m in a.methods.split(","):
        runs = {k: (lambda k=k, m=m: pkgs[k].render(scenes[k], m, a.size, a.size)) for k in pkgs}
        rn, rb = runs["new"](), runs["base"]()  # compile + warm up
        runs["new"](), runs["base"]()
        same = (
            np.array_equal(rn.visibility, rb.visibility, equal_nan=True)
            and np.array_equal(rn.image, rb.image, equal_nan=True)
            and _untimed(rn.stats) == _untimed(rb.stats)
        )
        t = {"new": [], "base": []}
        for r in range(a.reps):  # alternate which goes first
            for k in ("new", "base") if r % 2 == 0 else ("base", "new"):
                t0 = time.perf_counter()
                runs[k]()
                t[k].append(time.perf_counter() - t0)
        ratio = float(np.median(np.array(t["new"]) / np.array(t["base"])))
        print(
            f"  {m:22s} base {np.median(t['base']) * 1e3:7.2f} ms  new {np.median(t['new']) * 1e3:7.2f} ms  "
            f"new/base {ratio:.3f}  V, image, stats: {'bit for bit the same' if same else 'DIFFERENT'}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
