"""Stage commands: one module per stage, ``<stage>_command.py``, each a thin click shell over ``nsim.stages.<stage>.run``.

Modules import their stage lazily inside the command so that ``nsim ls`` stays fast.
"""

from __future__ import annotations

import click

# stage whose command module is nsim.commands.<stage>_command (its attribute ``command``: the click command or group)
COMMAND_MODULES = ("capture", "reconstruct", "train_scene", "train_human", "simulate", "render", "evaluate", "export",
                   "import_log", "register_log", "bake")


def register_commands(group: click.Group) -> None:
    import importlib

    for name in COMMAND_MODULES:
        mod = importlib.import_module(f"nsim.commands.{name}_command")
        group.add_command(mod.command)
