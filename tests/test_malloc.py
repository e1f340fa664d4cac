"""The allocator setting made at import (softshadows._malloc): on by default on glibc, off with
SOFTSHADOWS_TUNE_MALLOC=0, and it keeps repeated frames from page-faulting."""

import os
import subprocess
import sys

import pytest

PROBE = """
import resource, sys
import numpy as np
import softshadows._malloc as m
import softshadows
print(m._done)
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):  # a frame's worth of buffers, one above glibc's largest dynamic mmap threshold
    bufs = [np.ones(n // 8) for n in (6_000_000, 9_000_000, 12_000_000, 40_000_000)]
    del bufs
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _probe(env_value):
    env = dict(os.environ)
    if env_value is None:
        env.pop("SOFTSHADOWS_TUNE_MALLOC", None)
    else:
        env["SOFTSHADOWS_TUNE_MALLOC"] = env_value
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    done, faults = out.stdout.split()
    return done == "True", int(faults)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt")
def test_tuned_by_default_and_opt_out():
    assert _probe(None)[0]  # on by default
    tuned, faults = _probe("1")
    untuned, faults_untuned = _probe("0")
    assert tuned and not untuned
    # 20 frames of 67 MB: without the setting the 40 MB buffer is mmapped afresh every frame (faults
    # on each of its pages, fewer where transparent huge pages apply); with it, the heap pages of
    # the first frame are reused
    assert faults_untuned > 10_000
    assert faults < faults_untuned / 5
