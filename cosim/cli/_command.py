"""What every ``cosim`` command shares: one-line errors, text or JSON output, and readers of option values.

* :func:`_friendly` - a command's library errors become one ``error: ...`` line on stderr and an exit status
  (:data:`EXIT_RESULT`, :data:`EXIT_INPUT`, :data:`EXIT_INTERNAL`), its warnings one ``warning: ...`` line;
* :func:`_deprecated` - an old option spelling that still works says so, once, on stderr;
* :func:`_emit` - the result as text, or as one JSON object with ``--json`` (while a ``--json`` command runs, what
  FMUs print to the process's standard output goes to stderr: :func:`_fmu_prints_to_stderr`);
* :func:`_pairs`, :func:`_names`, :func:`_ranges` - ``NAME=VALUE``, ``A,B,...`` and ``NAME=LOW:HIGH`` options;
* :func:`_resolve_fmu` - an FMU argument: a path, ``bundled`` / ``bundled3`` for the bundled servo, ``bundled-split``
  for it split into two FMUs (an ``.ssp``).
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from ..errors import CosimDeprecationWarning, CosimError, InvalidSettingError
from ..numbers import WrittenNumber, parse_number

#: Exit status when the result does not meet what was asked (a failed spec, an unstable model): errors whose
#: class sets ``exit_status = 1``.
EXIT_RESULT = 1
#: Exit status for bad input or usage (every other :class:`~cosim.errors.CosimError`; click's usage errors too).
EXIT_INPUT = 2
#: Exit status for a bug of ours (an unexpected exception), after sysexits.h's EX_SOFTWARE.
EXIT_INTERNAL = 70


#: The process's standard output while :func:`_fmu_prints_to_stderr` sends file descriptor 1 to stderr.
_JSON_STREAM: list[Any] = []


def _emit(as_json: bool, payload: dict[str, Any], text: str) -> None:
    """Print `payload` as one JSON object with ``--json``, else `text`."""
    if as_json:
        if _JSON_STREAM:
            _JSON_STREAM[-1].write(json.dumps(payload, default=float) + "\n")
            _JSON_STREAM[-1].flush()
        else:
            click.echo(json.dumps(payload, default=float))
    else:
        click.echo(text)


@contextlib.contextmanager
def _fmu_prints_to_stderr():
    """Send file descriptor 1 to stderr for the duration, keeping the real standard output for :func:`_emit`.

    FMUs print from C (the OSP quarter truck's banners, logging FMUs): on stdout those lines would break a
    ``--json`` result that scripts parse. Where stdout has no file descriptor (click's test runner), nothing
    changes.
    """
    try:
        out_fd, err_fd = sys.stdout.fileno(), sys.stderr.fileno()
    except (AttributeError, OSError, io.UnsupportedOperation, ValueError):
        yield
        return
    sys.stdout.flush()
    saved = os.dup(out_fd)
    stream = os.fdopen(os.dup(saved), "w")
    os.dup2(err_fd, out_fd)
    _JSON_STREAM.append(stream)
    try:
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, out_fd)
        os.close(saved)
        _JSON_STREAM.pop()
        stream.close()


def _friendly(func: Callable) -> Callable:
    """Turn library errors into one line on stderr and an exit status: :data:`EXIT_INPUT` for bad input, the
    error's own ``exit_status`` where it has one (:data:`EXIT_RESULT`: an unstable model), :data:`EXIT_INTERNAL`
    for a bug of ours."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            with warnings.catch_warnings(), (_fmu_prints_to_stderr() if kwargs.get("as_json")
                                             else contextlib.nullcontext()):
                warnings.showwarning = _one_line_warning
                # Python hides DeprecationWarnings outside __main__; a command's user must see an old spelling's
                warnings.simplefilter("default", CosimDeprecationWarning)
                return func(*args, **kwargs)
        except CosimError as exc:
            if os.environ.get("COSIM_DEBUG"):
                raise
            click.echo(f"error: {exc}", err=True)
            sys.exit(int(getattr(exc, "exit_status", EXIT_INPUT)))
        except KeyboardInterrupt:
            click.echo("error: interrupted", err=True)
            sys.exit(130)
        except Exception as exc:  # a bug of ours: still one line, with the way to see more
            if os.environ.get("COSIM_DEBUG"):
                raise
            click.echo(f"error: internal error {type(exc).__name__}: {exc} (set COSIM_DEBUG=1 for the "
                       "traceback and report it)", err=True)
            sys.exit(EXIT_INTERNAL)

    return wrapper


def _one_line_warning(message: Warning | str, category: type[Warning], *_: Any, **__: Any) -> None:
    """``warning: ...`` on stderr, one line: not the ``file:line: UserWarning:`` of Python's default."""
    click.echo(f"warning: {' '.join(str(message).split())}", err=True)


def _deprecated(old: str, new: str) -> None:
    """Say on stderr that option spelling `old` still works but is deprecated in favour of `new`."""
    click.echo(f"warning: {old} is deprecated and will be removed; use {new}", err=True)


def _pairs(items: tuple[str, ...], option: str) -> dict[str, str]:
    """``("Fc=0.3", "Jm=300")`` -> {"Fc": "0.3", "Jm": "300"}; `option` names the option in the error."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise InvalidSettingError(f"{option} takes NAME=VALUE, got {item!r}")
        out[name.strip()] = value.strip()
    return out


def _settings(items: tuple[str, ...], option: str) -> dict[str, Any]:
    """``--set``/``--start`` values by name, each as its text writes it: a number (``0.3``, ``1/2257``), an
    array (``A=[[0,1],[-2,-3]]``, JSON), true/false, else the text itself (a String variable's value). The FMU's
    variable types check them when they are applied; a number keeps its text
    (:class:`~cosim.numbers.WrittenNumber`), which a String or a Binary variable takes as it is written
    (``Binary_input=626172``: the bytes 62 61 72).

    Examples
    --------
    >>> _settings(("Fc=1/4", "A=[[0,1],[-2,-3]]", "on=true", "label=left"), "--set")
    {'Fc': 0.25, 'A': [[0, 1], [-2, -3]], 'on': True, 'label': 'left'}
    >>> _settings(("Binary_input=626172",), "--set")["Binary_input"].text
    '626172'
    """
    out: dict[str, Any] = {}
    for name, text in _pairs(items, option).items():
        if text.startswith("["):
            try:
                out[name] = json.loads(text)
            except json.JSONDecodeError:
                raise InvalidSettingError(f"{option} {name}={text}: not an array; write rows in brackets, "
                                          f"e.g. {name}=[[0,1],[-2,-3]]") from None
        elif text.lower() in ("true", "false"):
            out[name] = text.lower() == "true"
        else:
            try:
                out[name] = WrittenNumber(parse_number(text, what=f"{option} {name}"), text)
            except InvalidSettingError:
                out[name] = text
    return out


def _resolve_fmu(path: str) -> Path:
    """`bundled` (or `bundled3` for FMI 3.0) names the bundled two-mass servo FMU; `bundled-split` the same servo
    as two FMUs wired by an SSP file (fmus/two_mass_servo_split)."""
    if path in ("bundled", "bundled3"):
        from ..plant.build import build_fmu

        return build_fmu(fmi_version="3.0" if path == "bundled3" else "2.0")
    if path == "bundled-split":
        from ..plant.build import build_ssp

        return build_ssp()
    return Path(path)


def _split(text: str) -> list[str]:
    """`text` split at its commas outside brackets: ``"a,pos=data[:,2]"`` -> ["a", "pos=data[:,2]"]."""
    items, depth, current = [], 0, []
    for char in text:
        depth += {"[": 1, "(": 1, "]": -1, ")": -1}.get(char, 0)
        if char == "," and depth == 0:
            items.append("".join(current))
            current = []
        else:
            current.append(char)
    return [*items, "".join(current)]


def _names(text: str, option: str) -> list[str]:
    """``"theta_m, omega_m"`` -> ["theta_m", "omega_m"] (commas inside brackets kept: ``pos=data[:,2]``); at
    least one name."""
    names = [n.strip() for n in _split(text) if n.strip()]
    if not names:
        raise InvalidSettingError(f"{option} takes comma-separated column names, got {text!r}")
    return names


def _ranges(items: tuple[str, ...], option: str) -> dict[str, tuple[float, float]]:
    """``("Fc=0:200",)`` -> {"Fc": (0.0, 200.0)}."""
    out = {}
    for name, text in _pairs(items, option).items():
        low, sep, high = text.partition(":")
        if not sep:
            raise InvalidSettingError(f"{option} takes NAME=LOW:HIGH, got {name}={text}")
        out[name] = (parse_number(low, what=f"{option} {name} low"), parse_number(high, what=f"{option} {name} high"))
    return out


def _decimate_option(text: str) -> int | str:
    """``--decimate``: "auto" or a positive integer (a one-line error otherwise)."""
    if text.strip() == "auto":
        return "auto"
    try:
        factor = int(text)
    except ValueError:
        factor = 0
    if factor < 1:
        raise InvalidSettingError(f"--decimate must be auto or a positive integer, got {text!r}")
    return factor
