"""Max |dV| of ``soft-shadow-map`` between a base revision and the working tree on every built-in
scene, both lights, at its defaults, with two passes, and with 128^2 maps (128x96 eye view). The
base runs in a subprocess from ``git archive <base>`` (its own JIT cache), so both are the code as
committed. Issue 16's exactness check for the sphere light's accumulation:

    PYTHONPATH=src python benchmarks/ssm_vdiff.py --base main
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile

SCENES = ("square", "spheres", "fence", "contact", "plant", "bunny")
CONFIGS = ({}, {"two_pass": True}, {"map_size": 128, "ssm_size": 128})


def dump(path: str) -> None:
    import numpy as np

    from softshadows import api
    from softshadows.compare import load

    out = {}
    for scene in SCENES:
        for light in ("sphere", "rect"):
            sc = load(scene, light)
            for kw in CONFIGS:
                r = api.render(sc, "soft-shadow-map", 128, 96, **kw)
                out[f"{scene}|{light}|{','.join(f'{k}={v}' for k, v in kw.items()) or 'defaults'}"] = r.visibility
    np.savez(path, **out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default="main", help="git revision of the base")
    ap.add_argument("--dump", help=argparse.SUPPRESS)  # internal: write V of this tree to DUMP
    a = ap.parse_args()
    if a.dump:
        dump(a.dump)
        return 0
    import numpy as np

    tmp = tempfile.mkdtemp(prefix="ssm_vdiff_")
    tar = subprocess.run(["git", "archive", a.base, "src"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", tmp], input=tar, check=True)
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    files = {}
    for name, src in (("base", os.path.join(tmp, "src")), ("new", os.path.join(here, "src"))):
        files[name] = os.path.join(tmp, f"{name}.npz")
        env = dict(os.environ, PYTHONPATH=src)
        subprocess.run([sys.executable, os.path.abspath(__file__), "--dump", files[name]], check=True, env=env)
    base, new = np.load(files["base"]), np.load(files["new"])
    worst = {"rect": 0.0, "sphere": 0.0}
    for k in base.files:
        d = float(np.nanmax(np.abs(base[k] - new[k]))) if np.any(np.isfinite(base[k])) else 0.0
        same = np.array_equal(base[k], new[k], equal_nan=True)
        light = k.split("|")[1]
        worst[light] = max(worst[light], d)
        print(f"{k:<45} {'bit-identical' if same else f'max |dV| = {d:.3g}'}")
    print(f"max |dV|: rect {worst['rect']:.3g}, sphere {worst['sphere']:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
