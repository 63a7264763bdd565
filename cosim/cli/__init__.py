"""The ``cosim`` command: a thin layer over the library.

Every command takes ``--json`` (one JSON object on stdout, progress and messages on stderr) and exits
non-zero with a one-line ``error: ...`` on bad input, never a traceback (set ``COSIM_DEBUG=1`` to see one).

One module per command group, each importing the rooms it drives only when its command runs (so that
``cosim --help`` stays quick); what they share is in :mod:`cosim.cli._command`:

* :mod:`~cosim.cli.fmu` - ``cosim fmu build``, ``cosim fmu info``;
* :mod:`~cosim.cli.simulate` - ``cosim simulate``, ``cosim data info``;
* :mod:`~cosim.cli.identify` - ``cosim identify``;
* :mod:`~cosim.cli.compare` - ``cosim compare``;
* :mod:`~cosim.cli.export` - ``cosim export``;
* :mod:`~cosim.cli.design` - ``cosim design pid``, ``cosim design mpc``;
* :mod:`~cosim.cli.validate` - ``cosim validate``;
* :mod:`~cosim.cli.diagnose` - ``cosim diagnose``;
* :mod:`~cosim.cli.reproduce` - ``cosim reproduce paper``;
* :mod:`~cosim.cli.demo` - ``cosim demo``.
"""

from __future__ import annotations

import sys
from typing import Any

import click

from . import compare, demo, design, diagnose, export, fmu, identify, reproduce, simulate, validate

__all__ = ["main"]


_NO_ARGS_IS_HELP = getattr(click.exceptions, "NoArgsIsHelpError", ())  # click >= 8.2


class _OneLineUsageErrors(click.Group):
    """click's usage errors (an unknown option, a value out of range, a missing argument) as one line,
    ``error: ... (see `cosim CMD --help`)``, exit status 2, like every other bad input; click prints four."""

    def main(self, args: Any = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> Any:
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            result = super().main(args, prog_name, complete_var, False, **extra)
        except click.UsageError as exc:
            if isinstance(exc, _NO_ARGS_IS_HELP):  # a group called bare: its help, as click shows it
                exc.show()
                sys.exit(exc.exit_code)
            where = f" (see `{exc.ctx.command_path} --help`)" if exc.ctx is not None else ""
            click.echo(f"error: {' '.join(exc.format_message().split())}{where}", err=True)
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            click.echo(f"error: {' '.join(exc.format_message().split())}", err=True)
            sys.exit(exc.exit_code)
        except click.Abort:
            click.echo("error: interrupted", err=True)
            sys.exit(130)
        sys.exit(result if isinstance(result, int) else 0)


@click.group(cls=_OneLineUsageErrors,
             context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 110})
@click.version_option(package_name="cosim")
def main() -> None:
    """cosim: identify, diagnose and control machines with FMU plants.

    \b
    Example:
      cosim fmu build
      cosim simulate bundled --input Tm=square:amp=500,freq=2 --duration 4 --dt 1/2257 -o data.csv
      cosim demo
    """


main.add_command(fmu.fmu)
main.add_command(simulate.simulate)
main.add_command(simulate.data)
main.add_command(identify.identify_command)
main.add_command(compare.compare_command)
main.add_command(export.export_command)
main.add_command(design.design)
main.add_command(validate.validate_command)
main.add_command(diagnose.diagnose_command)
main.add_command(reproduce.reproduce)
main.add_command(demo.demo)


if __name__ == "__main__":  # pragma: no cover
    main()
