"""Atomic file output: a crash or an error never leaves half a result behind.

Examples
--------
>>> import tempfile, pathlib
>>> target = pathlib.Path(tempfile.mkdtemp()) / "result.txt"
>>> with atomic_output(target) as tmp:
...     _ = tmp.write_text("done")
>>> target.read_text()
'done'
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["atomic_output", "check_file_format", "json_default", "write_text_atomic"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success rename it onto `path`, on error delete it.

    The parent folder is created if needed. The rename is atomic on POSIX and Windows (``os.replace``).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a result file gets the usual mode
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write `text` to `path` atomically and return the path."""
    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def check_file_format(data: Any, fmt: str, version: int, *, what: str, hint: str) -> Mapping[str, Any]:
    """Check the ``format`` and ``version`` keys of a parsed cosim JSON file; return `data`.

    Raises :class:`~cosim.errors.DataError` "not a cosim <what> ...; <hint>" for another format, and
    "<what> file version ... is newer than this cosim reads" for a newer version.
    """
    from .errors import DataError

    if not isinstance(data, Mapping) or data.get("format") != fmt:
        found = data.get("format") if isinstance(data, Mapping) else type(data).__name__
        raise DataError(f"not a cosim {what} (format {found!r}, expected {fmt!r}); {hint}")
    if not isinstance(data.get("version"), int) or data["version"] > version:
        noun = what.split()[0]
        raise DataError(f"{noun} file version {data.get('version')!r} is newer than this cosim reads "
                        f"({version}); upgrade cosim")
    return data


def json_default(value: Any) -> Any:
    """``json.dumps(..., default=json_default)``: numpy scalars and arrays as numbers and lists, paths as text.

    Examples
    --------
    >>> import json, numpy as np
    >>> json.dumps({"x": np.float64(0.5), "v": np.arange(2), "p": Path("a")}, default=json_default)
    '{"x": 0.5, "v": [0, 1], "p": "a"}'
    """
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")
