"""What a command writes, checked before it writes anything, and written all at once or not at all.

* :func:`check_outputs` - every output path of a command, checked before the first write: a suffix the option
  knows, not a folder, a folder to put it in that exists or can be made and is writable, no path given twice;
* :func:`staged_outputs` - several result files written beside their places and moved there together at the
  end: a command that fails half-way (an FMU that does not compile after the ``.mat`` was written) leaves none.

Examples
--------
>>> check_outputs({"-o/--output": ["model.xyz"]}, {"-o/--output": (".mat", ".fmu", ".json")})
Traceback (most recent call last):
...
cosim.errors.InvalidSettingError: -o/--output model.xyz: unknown suffix '.xyz'; use one of .mat, .fmu, .json
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path

from ..errors import InvalidSettingError

__all__ = ["check_outputs", "staged_outputs"]


def _writable_folder(path: Path) -> Path | None:
    """The nearest folder at or above `path` that exists, or None when a file stands in the way."""
    for folder in (path, *path.parents):
        if folder.exists():
            return folder if folder.is_dir() else None
    return None


def check_outputs(outputs: Mapping[str, Iterable[str | os.PathLike | None]],
                  suffixes: Mapping[str, Sequence[str]] | None = None) -> list[Path]:
    """Check every output path of a command before it writes anything; return them.

    Parameters
    ----------
    outputs : mapping
        Option name (as the user typed it, for the message) -> its paths (None entries are skipped).
    suffixes : mapping, optional
        Option name -> the suffixes it writes (lower case, with the dot); an option not named takes any.

    Raises
    ------
    InvalidSettingError
        One line naming the option and the path: an unknown suffix, a path that is a folder, a parent that is a
        file or not writable, or the same file given twice.
    """
    seen: dict[Path, str] = {}
    checked = []
    for option, paths in outputs.items():
        allowed = tuple((suffixes or {}).get(option, ()))
        for raw in paths:
            if raw is None:
                continue
            path = Path(raw)
            suffix = path.suffix.lower()
            if allowed and suffix not in allowed:
                raise InvalidSettingError(f"{option} {raw}: unknown suffix {path.suffix or '(none)'!r}; use one of "
                                          f"{', '.join(allowed)}")
            if path.is_dir():
                raise InvalidSettingError(f"{option} {raw} is a folder; give a file name, e.g. {raw}/result"
                                          f"{allowed[0] if allowed else ''}")
            folder = _writable_folder(path.absolute().parent)
            if folder is None:
                raise InvalidSettingError(f"{option} {raw}: a file stands where its folder should be; choose "
                                          "another path")
            if not os.access(folder, os.W_OK | os.X_OK):
                raise InvalidSettingError(f"{option} {raw}: cannot write in {folder}; choose a folder you can "
                                          "write to")
            key = path.absolute()
            if key in seen:
                twice = f"{option} {raw} is given twice" if seen[key] == option else \
                    f"{raw} is given to {seen[key]} and to {option}"
                raise InvalidSettingError(f"{twice}; give each file once")
            seen[key] = option
            checked.append(path)
    return checked


@contextlib.contextmanager
def staged_outputs(paths: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Yield, for each path, a place to write it under the same file name (in a hidden folder beside it, so
    that a name-dependent format such as an FMU, whose model identifier is its file stem, is the same); when
    the block ends without error every file is moved into place, else none is and the staging is removed.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> with staged_outputs([folder / "a.txt", folder / "b.txt"]) as (a, b):
    ...     _ = a.write_text("1"), b.write_text("2")
    ...     (folder / "a.txt").exists()
    False
    >>> sorted(p.name for p in folder.iterdir())
    ['a.txt', 'b.txt']
    """
    targets = [Path(p) for p in paths]
    stages: dict[Path, Path] = {}
    try:
        staged = []
        for target in targets:
            parent = target.absolute().parent
            if parent not in stages:
                try:
                    parent.mkdir(parents=True, exist_ok=True)
                    stages[parent] = Path(tempfile.mkdtemp(dir=parent, prefix=".cosim-staged-"))
                except OSError as exc:
                    raise InvalidSettingError(f"cannot write {target} ({exc.strerror or exc}); choose a folder you "
                                              "can write to") from None
            staged.append(stages[parent] / target.name)
        yield staged
        for target, place in zip(targets, staged, strict=True):
            if place.exists():
                os.replace(place, target)
    finally:
        for stage in stages.values():
            shutil.rmtree(stage, ignore_errors=True)
