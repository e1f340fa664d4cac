"""CLI: outputs exist and bad input gives one clear line and exit code 2."""

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from softshadows.cli import main, parse_size


def run(*args):
    p = subprocess.run([sys.executable, "-m", "softshadows", *args], capture_output=True, text=True, timeout=300)
    return p.returncode, p.stdout, p.stderr


def test_render_writes_png_and_exr(tmp_path):
    out, exr = tmp_path / "a.png", tmp_path / "a.exr"
    assert (
        main(["render", "square", "--method", "hard", "--size", "40x30", "-o", str(out), "--exr", str(exr), "-q"]) == 0
    )
    img = np.asarray(Image.open(out))
    assert img.shape == (30, 40, 3)
    from softshadows.shading import load_exr

    ch = load_exr(exr)
    v = ch["V"]
    assert v.shape == (30, 40)
    m = np.isfinite(v)
    assert m.any() and (v[m] == 0).any() and (v[m] == 1).any()  # the square's shadow is in view


def test_list_shows_methods_scenes_and_defaults(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for word in ("square", "bunny", "plant", "ground-truth", "hard", "samples=256", "map_size=1024"):
        assert word in out


@pytest.mark.parametrize(
    "args, needle",
    [
        (["render", "nosuchscene"], "nosuchscene"),
        (["render", "square", "--method", "nope"], "nope"),
        (["render", "square", "--method", "hard", "--set", "wat=1"], "wat"),
        (["render", "square", "--method", "hard", "--set", "map_size=-4"], "map_size"),
        (["render", "square", "--size", "0x10"], "size"),
        (["render", "square", "--size", "axb"], "size"),
        (["render", "square", "--set", "novalue"], "key=value"),
        (["render", "/nonexistent/x.obj"], "x.obj"),
    ],
)
def test_bad_input_one_line_exit_2(args, needle, capsys):
    code = main(args + ["-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert needle in err
    assert len(err.splitlines()) == 1 and "Traceback" not in err


def test_malformed_mesh_file_via_subprocess(tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    code, _out, err = run("render", str(bad), "--size", "16x16", "-q")
    assert code == 2, err
    assert "bad.obj" in err and "Traceback" not in err


def test_parse_size():
    assert parse_size("512x256") == (512, 256)
    assert parse_size("64") == (64, 64)
