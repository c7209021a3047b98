"""The ``sb3-memret`` command line: one module per command group, gathered under ``main``.

``rollout`` (a frozen controller under a prompt condition), ``stage1`` (``demos``, ``finetune``, ``serve``),
``training`` (``train``, ``tune``), ``evaluation`` (``eval``, ``ablate``, ``trace``, ``plot``, ``report``) and
``benchmark`` (MIKASA-Robo-VLA's protocol); ``options`` holds what they share.
"""

from __future__ import annotations

import sys

import click

from sb3_memret.cli.benchmark import benchmark
from sb3_memret.cli.evaluation import ablate, evaluate, plot, report, trace
from sb3_memret.cli.rollout import rollout
from sb3_memret.cli.stage1 import demos, finetune, serve
from sb3_memret.cli.training import train, tune


class MemretCli(click.Group):
    """Every mistake ends in one line that names the value and what is accepted, with a non-zero
    exit status and no traceback; SIGTERM (a scheduler's stop) is handled as Ctrl-C."""

    def main(self, *args, **kwargs):  # type: ignore[override]
        from sb3_memret.common.errors import (CudaNotFoundError, RendererNotFoundError, RunFolderError,
                                              WeightsNotLoadedError)
        from sb3_memret.common.workers import StopRequested, WorkerDiedError, exit_status, stop_signals_interrupt

        kwargs["standalone_mode"] = False  # errors come back here instead of click's usage block
        try:
            with stop_signals_interrupt():
                return super().main(*args, **kwargs)
        except click.exceptions.Abort as err:
            click.echo("Aborted.", err=True)
            sys.exit(exit_status(err.__cause__.signal_name if isinstance(err.__cause__, StopRequested) else "Ctrl-C"))
        except click.ClickException as err:
            ctx = getattr(err, "ctx", None)
            hint = f"  (see: {ctx.command_path} --help)" if isinstance(err, click.UsageError) and ctx else ""
            click.echo(f"Error: {err.format_message()}{hint}".replace("\n", " "), err=True)
            sys.exit(err.exit_code)
        except (WorkerDiedError, RendererNotFoundError, WeightsNotLoadedError, CudaNotFoundError, RunFolderError) as err:
            click.echo(f"Error: {err}", err=True)
            sys.exit(1)


@click.group(cls=MemretCli, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="sb3-memret")
def main() -> None:
    """A learnable external language memory for frozen robot policies."""


for _command in (rollout, demos, finetune, serve, train, tune, evaluate, ablate, trace, plot, report, benchmark):
    main.add_command(_command)

__all__ = ["main"]
