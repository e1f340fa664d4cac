"""The allocator setting (softshadows._malloc): importing the library leaves the process alone;
the CLI turns it on (off with SOFTSHADOWS_TUNE_MALLOC=0), and it keeps repeated frames from
page-faulting."""

import os
import subprocess
import sys

import pytest

PROBE = """
import resource, sys
import numpy as np
import softshadows._malloc as m
import softshadows
assert m._done is None, "importing the library must not change the allocator"
from softshadows.cli import main
main(["list"]) if sys.argv[-1] == "cli" else softshadows.tune_malloc()
print(m._done)
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):  # a frame's worth of buffers, one above glibc's largest dynamic mmap threshold
    bufs = [np.ones(n // 8) for n in (6_000_000, 9_000_000, 12_000_000, 40_000_000)]
    del bufs
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _probe(env_value, via="api"):
    env = dict(os.environ)
    if env_value is None:
        env.pop("SOFTSHADOWS_TUNE_MALLOC", None)
    else:
        env["SOFTSHADOWS_TUNE_MALLOC"] = env_value
    out = subprocess.run([sys.executable, "-c", PROBE, via], env=env, capture_output=True, text=True, check=True)
    done, faults = out.stdout.split()[-2:]
    return done == "True", int(faults)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt")
def test_tuned_by_default_and_opt_out():
    assert _probe(None, via="cli")[0]  # the CLI turns it on by default (import alone does not: PROBE asserts)
    tuned, faults = _probe("1")
    untuned, faults_untuned = _probe("0")
    assert tuned and not untuned
    # 20 frames of 67 MB: without the setting the 40 MB buffer is mmapped afresh every frame (faults
    # on each of its pages, fewer where transparent huge pages apply); with it, the heap pages of
    # the first frame are reused
    assert faults_untuned > 10_000
    assert faults < faults_untuned / 5
