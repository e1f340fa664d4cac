"""Output files: checked before any rendering, written atomically.

* :func:`check_outputs` validates every output path of a command up front (known extension, not a
  directory, its folder creatable and writable, no two outputs the same file) and raises
  :class:`OutputError` naming the option and the path.
* :func:`atomic_path` yields a temporary path beside the target (same folder, same extension) and
  renames it onto the target only when the writer succeeded; on any error the temporary file is
  removed, so a full disk, a file-size limit or an interrupted write never leaves a truncated file.
  :class:`OutputGroup` does the same for several files at once: all of them are renamed into place
  only after every one was written (a failing later output leaves no orphaned earlier one).
* Every ``OSError`` while writing becomes ``OutputError("cannot write PATH: reason")`` (the CLI
  prints ``softshadows: error: cannot write PATH: reason`` and exits with 2).
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager, suppress
from pathlib import Path

from .errors import SoftShadowsError

#: extensions by output kind
IMAGE_EXTS = (".png",)
EXR_EXTS = (".exr",)
JSON_EXTS = (".json",)


class OutputError(SoftShadowsError):
    """An output path is unusable or could not be written (``path``, ``reason`` when writing failed)."""

    def __init__(self, msg: str, path=None, reason: str | None = None):
        super().__init__(msg)
        self.path, self.reason = path, reason


def _write_error(shown, exc: BaseException, path=None) -> OutputError:
    reason = _reason(exc)
    return OutputError(f"cannot write {shown}: {reason}", path=str(path if path is not None else shown), reason=reason)


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return " ".join(str(exc).split()) or type(exc).__name__


def _nearest_existing(p: Path) -> Path:
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def check_folder(path, what: str) -> Path:
    """A folder that exists and is writable, or can be created; raises OutputError."""
    p = Path(os.path.abspath(os.path.expanduser(str(path))))
    if p.exists() and not p.is_dir():
        raise OutputError(f"{what} '{path}' is not a folder")
    anc = _nearest_existing(p)
    if not anc.is_dir():
        raise OutputError(f"{what} '{path}': '{anc}' is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise OutputError(f"{what} '{path}': folder '{anc}' is not writable")
    return p


def check_output(path, what: str, exts: tuple) -> Path:
    """One output file path: ``exts`` known extensions (lower case, with dot)."""
    if not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise OutputError(f"{what} must be a file path, got {path!r}")
    p = Path(os.path.abspath(os.path.expanduser(str(path))))
    if str(path).endswith(os.sep) or p.is_dir():
        raise OutputError(f"{what} '{path}' is a folder, not a file")
    if p.suffix.lower() not in exts:
        raise OutputError(f"{what} '{path}' must end in {' or '.join(exts)}")
    if p.exists() and not os.access(p, os.W_OK):
        raise OutputError(f"{what} '{path}' is not writable")
    check_folder(p.parent, f"{what} '{path}': folder")
    return p


def check_outputs(items) -> list[Path]:
    """``items``: (what, path, exts) with path None for an output not asked for. Validates each
    and that no two are the same file; returns the absolute paths (None kept)."""
    out, seen = [], {}
    for what, path, exts in items:
        if path is None:
            out.append(None)
            continue
        p = check_output(path, what, exts)
        key = os.path.normcase(os.path.realpath(p))
        if key in seen:
            raise OutputError(f"{what} and {seen[key]} are the same file '{path}'")
        seen[key] = what
        out.append(p)
    return out


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: mode of written files: what open() would give (mkstemp's own 0600 would hide outputs from others)
_FILE_MODE = 0o666 & ~_umask()


def _temp_beside(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    try:
        os.fchmod(fd, _FILE_MODE)
    finally:
        os.close(fd)
    return Path(tmp)


def _remove(p: Path) -> None:
    with suppress(OSError):
        p.unlink()


@contextmanager
def atomic_path(path):
    """``with atomic_path(target) as tmp: write(tmp)``: ``tmp`` is renamed onto ``target`` when the
    block succeeds and removed when it fails; OSError -> OutputError naming ``target``."""
    target = Path(os.path.abspath(os.path.expanduser(str(path))))
    try:
        tmp = _temp_beside(target)
    except OSError as exc:
        raise _write_error(path, exc, target) from None
    try:
        yield tmp
        os.replace(tmp, target)
    except OSError as exc:
        _remove(tmp)
        raise _write_error(path, exc, target) from None
    except BaseException:
        _remove(tmp)
        raise


class OutputGroup:
    """Several outputs committed together::

    with OutputGroup() as g:
        save_png(g.path(out), img)
        save_exr(g.path(exr), chans)
    # here both files are in place, or neither (the temporary files are removed)
    """

    def __init__(self):
        self._pending: list[tuple[Path, Path, str]] = []

    def path(self, target) -> Path:
        t = Path(os.path.abspath(os.path.expanduser(str(target))))
        try:
            tmp = _temp_beside(t)
        except OSError as exc:
            raise _write_error(target, exc, t) from None
        self._pending.append((tmp, t, str(target)))
        return tmp

    def __enter__(self):
        return self

    def __exit__(self, et, ev, tb):
        if et is not None:
            for tmp, _t, _n in self._pending:
                _remove(tmp)
            # a writer's error names the temporary file: name the user's path instead
            if isinstance(ev, OutputError) and ev.reason is not None:
                shown = next((n for tmp, _t, n in self._pending if str(tmp) == ev.path), None)
                if shown is not None:
                    raise OutputError(f"cannot write {shown}: {ev.reason}", path=shown, reason=ev.reason) from None
            elif isinstance(ev, OSError):
                name = getattr(ev, "filename", None)
                shown = next((n for tmp, _t, n in self._pending if str(tmp) == str(name)), name)
                raise _write_error(shown, ev) from None
            return False
        for i, (tmp, t, name) in enumerate(self._pending):
            try:
                os.replace(tmp, t)
            except OSError as exc:
                for tmp2, _t, _n in self._pending[i:]:
                    _remove(tmp2)
                raise _write_error(name, exc, t) from None
        return False


def write_bytes(path, data: bytes) -> str:
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return str(path)


def write_text(path, text: str) -> str:
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
    return str(path)


def write_json(path, doc, indent: int = 2) -> str:
    return write_text(path, json.dumps(doc, indent=indent))
