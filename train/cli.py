"""The `planar-pose` command: one sub-command (group) per step of the pipeline.

Each step lives in its own module and is registered here. Command modules must not import
torch at import time (the service install has no torch): import it inside the command.
"""

from __future__ import annotations

import typer

from service.cli import app as service_commands
from train.commands import corpus as corpus_commands
from train.commands import data as data_commands
from train.commands import model as model_commands
from train.commands import object as object_commands
from train.commands import real as real_commands

app = typer.Typer(
    name="planar-pose",
    help="Coarse camera pose region of a planar object: data, train, evaluate, export, serve.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)

app.add_typer(model_commands.app)  # train, evaluate, export, realset
app.add_typer(service_commands)  # serve
app.add_typer(real_commands.app)  # label, baseline, compare
app.add_typer(data_commands.app)  # data make | grid | sheet | roll
app.add_typer(corpus_commands.app)  # corpus add | frames | charuco | check | sets | report
app.add_typer(object_commands.app)  # object new | train

if __name__ == "__main__":  # python -m train.cli: the command from a source tree
    app()
