"""One-line command summaries for the command lists of ``cornerman --help`` and its groups.

typer 0.29 lists a command by its docstring's first paragraph but, in its default rich markup
mode, keeps that paragraph's line breaks, so a wrapped docstring showed as a ragged row broken
mid-sentence. The summary is that paragraph on one line; ``cornerman CMD --help`` is unchanged."""

from __future__ import annotations

import inspect

import typer


def summary(doc: str) -> str:
    """The first paragraph of ``doc`` with its line breaks and runs of spaces made single spaces."""
    return " ".join(inspect.cleandoc(doc).split("\n\n")[0].split())


def one_line_summaries(app: typer.Typer) -> None:
    """Give every command of ``app`` and of its sub-apps without a ``short_help`` its one-line summary."""
    for info in app.registered_commands:
        doc = info.help or (inspect.getdoc(info.callback) if info.callback else None)
        if info.short_help is None and doc:
            info.short_help = summary(doc)
    for group in app.registered_groups:
        if group.typer_instance is not None:
            one_line_summaries(group.typer_instance)
