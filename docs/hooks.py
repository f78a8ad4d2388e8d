"""mkdocs hook: the command-line reference (docs/cli.md) is generated from click's help at build time.

The page holds a marker, ``<!-- drivecal-cli-reference -->``, that this hook replaces with ``drivecal --help``
and every command's ``--help``, rendered through click's own API (``Command.get_help``) exactly as the
terminal shows them. Listing the commands and rendering their help imports no JAX (the CLI loads its
numerical dependencies when a command runs), so this takes well under a second.
"""

from __future__ import annotations

import click

MARKER = "<!-- drivecal-cli-reference -->"
WIDTH = 100  # characters a help line may take


def _help(command: click.Command, info_name: str, parent: click.Context | None) -> tuple[str, click.Context]:
    ctx = click.Context(command, info_name=info_name, parent=parent, terminal_width=WIDTH, max_content_width=WIDTH)
    return command.get_help(ctx), ctx


def cli_reference() -> str:
    """Markdown: the group's help, then one section per command with its help, in ``drivecal --help``'s order."""
    from drivecal.cli import cli

    text, root = _help(cli, "drivecal", None)
    parts = ["## `drivecal`", "", "```text", "$ drivecal --help", text, "```", ""]
    for name in cli.list_commands(root):
        command = cli.get_command(root, name)
        if command is None or command.hidden:
            continue
        text, _ = _help(command, name, root)
        parts += [f"## `drivecal {name}`", "", "```text", f"$ drivecal {name} --help", text, "```", ""]
    return "\n".join(parts)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, cli_reference())
    return markdown
