"""Regenerate ``src/softshadows/data/bunny.npz``, the decimated Stanford bunny of the ``bunny`` scene.

Development-only tool (needs ``fast-simplification``, which the package does not depend on)::

    pip install fast-simplification
    python benchmarks/make_bunny_data.py [--source path/to/stanford-bunny.obj] [--faces 10000]

Steps: load the OBJ with trimesh (no processing), merge duplicate vertices, quadric-decimate to
about ``--faces`` triangles with fast-simplification, drop degenerate and unreferenced geometry,
normalize (uniform scale to ``--height`` units tall, bottom at y = 0, bounding box centered on
x = z = 0; the source is already y up), and save float32 vertices / int32 faces with
``numpy.savez_compressed``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "src" / "softshadows" / "data" / "bunny.npz"


def make(source: Path, out: Path, faces: int = 10_000, height: float = 1.2) -> tuple[int, int]:
    import fast_simplification
    import trimesh

    mesh = trimesh.load(source, process=False, force="mesh")
    mesh.merge_vertices()
    v0 = np.asarray(mesh.vertices, np.float64)
    f0 = np.asarray(mesh.faces, np.int64)
    v, f = fast_simplification.simplify(
        v0.astype(np.float32), f0.astype(np.int32), target_reduction=1.0 - faces / len(f0)
    )
    m = trimesh.Trimesh(np.asarray(v, np.float64), np.asarray(f, np.int64), process=True)
    m.update_faces(m.nondegenerate_faces())
    m.remove_unreferenced_vertices()
    v = np.asarray(m.vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    s = height / (hi[1] - lo[1])
    v = (v - np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])) * s
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, vertices=v.astype(np.float32), faces=np.asarray(m.faces, np.int32))
    return len(v), len(m.faces)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--source", type=Path, required=True, help="path of stanford-bunny.obj (Stanford 3D Scanning Repository)"
    )
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--faces", type=int, default=10_000)
    ap.add_argument("--height", type=float, default=1.2)
    a = ap.parse_args(argv)
    nv, nf = make(a.source, a.out, a.faces, a.height)
    print(f"wrote {a.out}: {nv} vertices, {nf} faces, {a.out.stat().st_size / 1024:.1f} KiB")


if __name__ == "__main__":
    main()
