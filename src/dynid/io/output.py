"""Writing an output folder all at once: nothing half-written on failure."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from dynid.errors import InputError

__all__ = ["staged_output"]


def _chmod_as_mkdir(path: Path) -> None:
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o777 & ~umask)


@contextlib.contextmanager
def staged_output(out_dir: str | Path) -> Iterator[Path]:
    """Yield a private staging folder; on success move its files into ``out_dir``.

    If the body raises, the staging folder is removed and ``out_dir`` is left as it
    was (not created when it did not exist), so a failed run never leaves partial
    output behind.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"output folder {out} exists and is not a folder")
    parent = out.parent if str(out.parent) else Path(".")
    created = [p for p in (parent, *parent.parents) if not p.exists()]  # deepest first
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.staging-", dir=parent))
        _chmod_as_mkdir(stage)  # mkdtemp makes 0700; the output folder gets the usual mode
    except OSError as exc:
        raise InputError(f"cannot create output folder {out} ({exc.strerror or exc})") from None
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        for p in created:  # folders made for the output, removed if still empty
            with contextlib.suppress(OSError):
                p.rmdir()
        raise
    try:
        if not out.exists():
            os.replace(stage, out)
            return
        for item in sorted(stage.rglob("*")):
            rel = item.relative_to(stage)
            target = out / rel
            if item.is_dir():
                target.mkdir(parents=True, exist_ok=True)
            else:
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(item, target)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
