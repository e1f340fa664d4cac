"""The cold-cache check and the first-run message (softshadows._warm), in a fresh process with an
empty NUMBA_CACHE_DIR (nothing is compiled: the check only reads the cache indexes)."""

import os
import subprocess
import sys

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src")

PROBE = """
import io
from softshadows.compare import resolve_methods
from softshadows import _warm
resolve_methods("all")  # imports every method module, so every kernel is registered
buf = io.StringIO()
a = _warm.say_if_cold(buf)
b = _warm.say_if_cold(buf)
print(a, b, _warm.cache_state(), repr(buf.getvalue()))
print(_warm.start_warmup("bunny", "rect", 16, 16, ["hard"], {}))
"""


def _probe(cache_dir, **env):
    e = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), PYTHONPATH=SRC, **env)
    return subprocess.run([sys.executable, "-c", PROBE], env=e, capture_output=True, text=True, check=True).stdout


def test_empty_cache_is_cold_and_said_once(tmp_path):
    out = _probe(tmp_path, SOFTSHADOWS_WARMUP="0").splitlines()
    # cold both times, (cold, writable), and the message exactly once
    assert out[0] == f"True True (True, True) {_message()!r}", out
    assert out[1] == "None"  # SOFTSHADOWS_WARMUP=0: no helper process


def _message():
    sys.path.insert(0, SRC)
    from softshadows._warm import COLD_MESSAGE

    return COLD_MESSAGE + "\n"
