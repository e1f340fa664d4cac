"""Print what ``tools/compile_profile`` recorded (see its ``sitecustomize`` docstring): the total,
the time per Numba pass, and the kernels by exclusive compile time (summed over their signatures
and processes; a parallel kernel's gufunc on its own line), with their LLVM time.

    python tools/compile_profile/report.py DIR [--top 40]
"""

import argparse
import collections
import glob
import json
import os


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder")
    ap.add_argument("--top", type=int, default=40)
    a = ap.parse_args()
    excl, llvm = [], []
    files = glob.glob(os.path.join(a.folder, "cprof-*.json"))
    if not files:
        print(f"no cprof-*.json in {a.folder}")
        return 2
    for f in files:
        with open(f) as fh:
            j = json.load(fh)
        excl += j["excl"]
        llvm += j["llvm"]

    def name(k):
        gufunc = " [gufunc]" if k.endswith(" [gufunc]") else ""
        return k.split(" ")[0] + gufunc

    per_pass, per_kernel, per_llvm = collections.Counter(), collections.Counter(), collections.Counter()
    for k, p, v in excl:
        per_pass[p] += v
        per_kernel[name(k)] += v
    for k, _p, v in llvm:
        per_llvm[name(k)] += v
    total = sum(per_kernel.values())
    print(f"{len(files)} process(es): {total:.1f} s compiling, {sum(per_llvm.values()):.1f} s of it in LLVM")
    print("by pass:")
    for p, v in per_pass.most_common(12):
        print(f"  {v:7.2f} s  {p}")
    small = [v for v in per_kernel.values() if v < 0.5]
    print(f"kernels: {len(per_kernel)}; {len(small)} under 0.5 s take {sum(small):.1f} s")
    print("  exclusive  llvm  kernel")
    for k, v in per_kernel.most_common(a.top):
        print(f"  {v:7.2f} {per_llvm[k]:6.2f}  {k}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
