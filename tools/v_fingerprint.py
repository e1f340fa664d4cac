"""Fingerprint V of every built-in scene x method x light shape (for refactors that must not change V).

python tools/v_fingerprint.py OUT.npz            # write
python tools/v_fingerprint.py OUT.npz --check REF.npz   # write and compare bit for bit
"""

from __future__ import annotations

import argparse
import hashlib
import sys

import numpy as np

import softshadows as ss
from softshadows.scene.builtin import BUILTIN


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--check", default=None)
    ap.add_argument("--size", default="96x72")
    ap.add_argument("--methods", default=None)
    a = ap.parse_args(argv)
    w, h = (int(x) for x in a.size.split("x"))
    names = a.methods.split(",") if a.methods else list(ss.methods())
    arrays = {}
    for sc in BUILTIN:
        for light in ("rect", "sphere"):
            scene = ss.load_scene(sc, light=light)
            for m in names:
                meth = ss.methods()[m]
                if light not in meth.light_shapes:
                    continue
                kw = {"samples": 16} if m == "ground-truth" else {}
                v = ss.render(scene, m, w, h, seed=1, **kw).visibility
                key = f"{sc}/{light}/{m}"
                arrays[key] = v
                print(key, hashlib.sha1(np.ascontiguousarray(v).tobytes()).hexdigest()[:12], flush=True)
    np.savez_compressed(a.out, **arrays)
    if a.check:
        ref = np.load(a.check)
        bad = 0
        for k in ref.files:
            if k not in arrays:
                print("missing", k)
                bad += 1
            elif not np.array_equal(ref[k], arrays[k], equal_nan=True):
                d = np.nanmax(np.abs(ref[k].astype(np.float64) - arrays[k]))
                print("DIFFERS", k, "max |dV| =", d)
                bad += 1
        print(f"{len(ref.files) - bad} of {len(ref.files)} bit-identical")
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
