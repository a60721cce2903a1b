"""A Sphinx directive that writes the reference of the ``scene-estimator`` commands from the real
``argparse`` parser, at build time, so that the documentation cannot drift from ``--help``.

Usage in a MyST page::

    ```{cli-reference}
    ```

    ```{cli-reference} run
    ```

The parser is :func:`experiments.cli.build_parser` with every subcommand's arguments (``main``
builds it with the invoked subcommand's only, so that a command imports only its own code); nothing
is run.
"""
from __future__ import annotations

import argparse

from docutils import nodes
from docutils.parsers.rst import Directive


def subcommands(parser: argparse.ArgumentParser) -> dict[str, tuple[str, argparse.ArgumentParser]]:
    """name -> (one-line help, subparser), in the order ``main`` adds them."""
    out = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, sub in action.choices.items():
                out[name] = (helps.get(name, ""), sub)
    return out


def _invocation(action: argparse.Action) -> str:
    if not action.option_strings:
        return action.metavar or action.dest
    if action.nargs == 0:
        return ", ".join(action.option_strings)
    formatter = argparse.HelpFormatter("x")
    default = action.dest.upper()
    args = formatter._format_args(action, default)
    return ", ".join(f"{opt} {args}" for opt in action.option_strings)


def _help(action: argparse.Action) -> str:
    text = action.help or ""
    if "%(" in text:
        params = dict(vars(action), prog="scene-estimator")
        for name in list(params):
            if params[name] is argparse.SUPPRESS:
                del params[name]
        if params.get("choices") is not None:
            params["choices"] = ", ".join(str(c) for c in params["choices"])
        try:
            text = text % params
        except (KeyError, TypeError, ValueError):
            pass
    extra = []
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        extra.append("choices: " + ", ".join(str(c) for c in action.choices))
    if (action.default is not None and action.default is not argparse.SUPPRESS and action.nargs != 0
            and action.option_strings and "default" not in text.lower()):
        extra.append(f"default: {action.default!r}")
    if action.required and action.option_strings:
        extra.append("required")
    if extra:
        text = f"{text} ({'; '.join(extra)})" if text else "; ".join(extra)
    return text


def _para(text: str) -> nodes.paragraph:
    return nodes.paragraph(text, text)


def command_section(name: str, short: str, parser: argparse.ArgumentParser, document) -> nodes.section:
    section_id = nodes.make_id(f"command-{name}")
    section = nodes.section(ids=[section_id], names=[section_id])
    document.note_explicit_target(section)
    section += nodes.title(f"scene-estimator {name}", f"scene-estimator {name}")
    if short:
        section += _para(short[0].upper() + short[1:] + ".")
    usage = parser.format_usage().strip()
    if usage.startswith("usage: "):
        usage = usage[len("usage: "):]
    section += nodes.literal_block(usage, usage, language="text")
    if parser.description:
        section += _para(parser.description)
    for group in parser._action_groups:
        actions = [a for a in group._group_actions
                   if a.help is not argparse.SUPPRESS and not isinstance(a, argparse._HelpAction)]
        if not actions:
            continue
        title = group.title or "options"
        rubric = nodes.rubric(title, title)
        section += rubric
        if group.description:
            section += _para(group.description)
        items = nodes.definition_list()
        for action in actions:
            term = nodes.term()
            term += nodes.literal(_invocation(action), _invocation(action))
            definition = nodes.definition()
            definition += _para(_help(action) or "(no help text)")
            items += nodes.definition_list_item("", term, definition)
        section += items
    if parser.epilog:
        section += _para(parser.epilog)
    return section


class CliReference(Directive):
    """``cli-reference [COMMAND ...]``: one section per subcommand (all when none is named)."""

    optional_arguments = 20
    has_content = False

    def run(self):
        from experiments.cli import build_parser

        parser = build_parser()
        subs = subcommands(parser)
        names = self.arguments or list(subs)
        document = self.state.document
        out = []
        for name in names:
            if name not in subs:
                raise self.error(f"no subcommand {name!r} (have: {', '.join(subs)})")
            short, sub = subs[name]
            out.append(command_section(name, short, sub, document))
        return out


def setup(app):
    app.add_directive("cli-reference", CliReference)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
