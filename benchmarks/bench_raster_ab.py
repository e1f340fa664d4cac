"""A/B timing of the shared rasterizer against the one of another git revision, in one process.

    PYTHONPATH=src python benchmarks/bench_raster_ab.py --rev 82e1f56 [--runs 15] [--only gbuffer]

Extracts ``src/softshadows/raster/``, ``src/softshadows/geometry/`` (``raster/view.py`` imports
it), ``_jit.py`` and ``errors.py`` of ``--rev`` into a package ``softshadows_ref`` under
``$TMPDIR/softshadows_ref_<rev>`` (kept, with Numba's cache; delete it after a failed extraction),
checks that both give identical outputs on the timed cases, then times the fill-bound paths of
``bench_raster_fill.py --bench`` (plus the penumbra program's min-blend with hierarchical culling)
for both, interleaved run by run after a warm-up (the order alternates between runs), and prints
the median wall and CPU (process, all threads) time of each and the medians of the per-run ratios
(this tree / the revision). On a shared, loaded machine the CPU-time ratio is the steadier one.

Read the ratios against an A/A run (``--rev HEAD`` on a clean tree): on 2026-12-03 one gave
0.84-0.95 wall and 0.89-0.96 CPU, not 1.0 (the extracted copy ran slower; cause not found), and a
change measured the same against 9ee071c.
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import softshadows
from softshadows.api import eye_view
from softshadows.raster.programs import PROGRAM_ATTRIBUTE, PROGRAM_PENUMBRA

shadowmap = importlib.import_module("softshadows.methods.shadowmap")
_FILES = ("src/softshadows/_jit.py", "src/softshadows/errors.py")
#: the raster package and what it imports from the package (``raster/view.py``: ``geometry``)
_PKGS = ("src/softshadows/raster/", "src/softshadows/geometry/")


def extract(rev: str, root: Path) -> Path:
    """Write the raster package of ``rev`` (and the packages it imports) as package
    ``softshadows_ref`` under ``root``."""
    repo = Path(__file__).resolve().parents[1]
    names = []
    for sub in _PKGS:
        names += subprocess.run(
            ["git", "ls-tree", "--name-only", rev, sub], cwd=repo, check=True, capture_output=True, text=True
        ).stdout.split()
        (root / "softshadows_ref" / sub.removeprefix("src/softshadows/")).mkdir(parents=True, exist_ok=True)
    pkg = root / "softshadows_ref"
    (pkg / "__init__.py").write_text("")
    for name in [*names, *_FILES]:
        if not name.endswith(".py"):
            continue
        text = subprocess.run(
            ["git", "show", f"{rev}:{name}"], cwd=repo, check=True, capture_output=True, text=True
        ).stdout
        rel = name.removeprefix("src/softshadows/")
        (pkg / rel).write_text(text)
    return pkg


def cases(R):
    """(name, fn) pairs for rasterizer module namespace ``R`` (``softshadows.raster`` or the ref)."""
    sc = softshadows.load_scene("bunny")
    fl = sc.flat
    ev = eye_view(sc, 512, 512)
    lv = shadowmap.fit_light_view(sc, 1024)
    ov = shadowmap.fit_light_view(sc, 1024, ortho=True)
    occ = np.ascontiguousarray(fl.faces[fl.occluder])
    H, W = lv.height, lv.width
    rng = np.random.default_rng(0)
    ca = rng.random((len(fl.faces), 3))
    zero = np.zeros((H, W), np.float32)
    buf = np.empty((H, W), np.float32)
    d, _ = R.rasterize_depth(lv, fl.vertices, fl.faces)
    img = np.where(np.isfinite(d), d * 1.05 + 0.01, np.inf).astype(np.float32)
    zs = float(d[np.isfinite(d)].max())
    za = rng.uniform(0.0, 2.0, size=(len(fl.faces), 3)) * zs
    za[::2] = za[::2, :1]  # half the triangles with a constant attribute (the value test)
    pen = np.array([0.5, 0.001, 1.0])

    def mb_attr():
        buf.fill(np.inf)
        R.rasterize_min_blend(lv, fl.vertices, fl.faces, PROGRAM_ATTRIBUTE, ca, zero, np.zeros(1), buf)
        return buf.copy()

    def mb_pen():
        buf.fill(1.0)
        R.rasterize_min_blend(lv, fl.vertices, fl.faces, PROGRAM_PENUMBRA, za, img, pen, buf, cull_discarded=True)
        return buf.copy()

    def gbuf():
        g = R.rasterize(ev, fl.vertices, fl.faces)
        return g.position, g.normal, g.depth, g.tri_id, g.bary, g.mask

    def frags():
        f = R.rasterize_fragments(lv, fl.vertices, occ)
        return f.pixel, f.tri, f.bary, f.depth

    return [
        ("eye gbuffer 512^2 bunny", gbuf),
        ("depth 1024^2 light bunny (all faces)", lambda: R.rasterize_depth(lv, fl.vertices, fl.faces)),
        ("depth 1024^2 light bunny (occluders)", lambda: R.rasterize_depth(lv, fl.vertices, occ)),
        ("depth 1024^2 ortho light bunny", lambda: R.rasterize_depth(ov, fl.vertices, fl.faces)),
        ("fragments 1024^2 light bunny (occluders)", frags),
        ("min_blend attr 1024^2 light bunny", mb_attr),
        ("min_blend penumbra+cull 1024^2 light bunny", mb_pen),
    ]


def _same(a, b) -> bool:
    if isinstance(a, tuple):
        return all(_same(x, y) for x, y in zip(a, b, strict=True))
    return np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rev", required=True, help="git revision to compare with (e.g. the commit before a refactor)")
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--only", default="", help="time only the cases whose name contains this")
    a = ap.parse_args()
    import numba

    # a directory per revision, kept: Numba's cache of the revision's kernels lives there
    rev = subprocess.run(
        ["git", "rev-parse", "--short", a.rev],
        cwd=Path(__file__).resolve().parents[1],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    root = Path(tempfile.gettempdir()) / f"softshadows_ref_{rev}"
    if not (root / "softshadows_ref").exists():
        extract(rev, root)
    sys.path.insert(0, str(root))
    ref = importlib.import_module("softshadows_ref.raster")
    new = importlib.import_module("softshadows.raster")
    print(f"threads {numba.get_num_threads()}; this tree vs {rev}; median of {a.runs} interleaved runs")
    cn = [c for c in cases(new) if a.only in c[0]]
    cr = [c for c in cases(ref) if a.only in c[0]]
    for (name, fn), (_, fr) in zip(cn, cr, strict=True):
        if not _same(fn(), fr()):  # also the warm-up (compilation)
            print(f"{name}: OUTPUTS DIFFER")
            sys.exit(1)
    print(f"{'':45s} {'wall time':^27s} {'CPU time (all threads)':^27s}")
    print(f"{'case':45s} {'rev ms':>9s} {'this ms':>9s} {'ratio':>7s} {'rev ms':>9s} {'this ms':>9s} {'ratio':>7s}")
    for (name, fn), (_, fr) in zip(cn, cr, strict=True):
        tn, tr, cn_, cr_ = [], [], [], []
        for r in range(a.runs):
            pair = ((fn, tn, cn_), (fr, tr, cr_)) if r % 2 == 0 else ((fr, tr, cr_), (fn, tn, cn_))
            for f, acc, cacc in pair:
                c0 = time.process_time()
                t0 = time.perf_counter()
                f()
                acc.append(time.perf_counter() - t0)
                cacc.append(time.process_time() - c0)
        wr = np.median(np.array(tn) / np.array(tr))
        cr = np.median(np.array(cn_) / np.array(cr_))
        print(
            f"{name:45s} {np.median(tr) * 1e3:9.2f} {np.median(tn) * 1e3:9.2f} {wr:7.3f}"
            f" {np.median(cr_) * 1e3:9.2f} {np.median(cn_) * 1e3:9.2f} {cr:7.3f}",
            flush=True,
        )


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    main()
