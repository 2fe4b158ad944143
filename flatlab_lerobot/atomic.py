"""Crash-safe writes of single files: the content goes to a temporary file beside the target, which then
replaces the target in one ``os.replace``.  A crash (or Ctrl-C) mid-write leaves the old file, or none,
never half of a new one; the temporary file is removed on any error.

* :func:`replacing` -- a context manager giving the temporary path to write with any writer
  (``fig.savefig``, ``pq.write_table``, a recorder's ``save``);
* :func:`write_text` / :func:`write_json` -- the common cases.

The temporary name is unique (``tempfile.mkstemp``), so two processes writing the same target never
write into each other's temporary file; the last ``os.replace`` wins.  The file gets the permissions
any newly created file would (``mkstemp`` alone makes it 0600).
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


@contextmanager
def replacing(path: str | Path, *, mkdir: bool = True) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder; when the block ends without an error, it replaces
    ``path``.  ``mkdir``: create the folder first."""
    path = Path(path)
    if mkdir:
        path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".partial{path.suffix}")
    tmp = Path(name)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)
        os.close(fd)
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: str | Path, text: str, *, mkdir: bool = True) -> None:
    """Write ``text`` to ``path`` crash-safely."""
    with replacing(path, mkdir=mkdir) as tmp:
        tmp.write_text(text)


def write_json(path: str | Path, obj: Any, *, indent: int | None = 1) -> None:
    """Write ``obj`` as JSON (and a final newline) to ``path`` crash-safely."""
    write_text(path, json.dumps(obj, indent=indent) + "\n")
