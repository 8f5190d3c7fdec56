"""MkDocs hook (mkdocs.yml `hooks`): pages generated from the code at build time, so they cannot drift from it.

- reference/cli.md: every `jiggle` command's --help, from the argparse parser itself (jiggle.sim.app.cli).
- reference/parameters.md: the keyable jiggle parameters' table, from jiggle.sim.jiggle.keyed.PARAMETERS, and the
  chains', from jiggle.sim.chain.params.CHAIN_PARAMETERS (<!-- jiggle:chain-parameters -->).
- a module's docstring where a page has <!-- jiggle:doc MODULE --> (the scene file's layout, the npz's keys).
A page asks for them with the markers <!-- jiggle:cli -->, <!-- jiggle:parameters --> and <!-- jiggle:doc M -->.
"""
from __future__ import annotations

import importlib
import inspect
import os
import re


def _cli() -> str:
    os.environ["COLUMNS"] = "110"                 # argparse wraps to the terminal: one width for every build
    from jiggle.sim.app.cli import build_parser
    top = build_parser()
    out = ["## jiggle", "", "```text", top.format_help().rstrip(), "```", ""]
    sub = next(a for a in top._actions if getattr(a, "choices", None) and "bake" in a.choices)
    for name, parser in sub.choices.items():
        out += [f"## jiggle {name}", "", "```text", parser.format_help().rstrip(), "```", ""]
    return "\n".join(out)


def _parameters() -> str:
    from jiggle.sim.jiggle.keyed import PARAMETERS
    rows = ["| parameter | what it does | range | unit | default |", "| --- | --- | --- | --- | --- |"]
    for name, p in PARAMETERS.items():
        rows.append(f"| `{name}` | {p.what} | {p.range_text} | {p.unit or ''} | {p.default} |")
    return "\n".join(rows)


def _chain_parameters() -> str:
    from jiggle.sim.chain.params import CHAIN_PARAMETERS
    rows = ["| parameter | flag | what it does | range | unit | default |", "| --- | --- | --- | --- | --- | --- |"]
    for name, p in CHAIN_PARAMETERS.items():
        rows.append(f"| `{name}` | `--chain-{name}` | {p.what} | {p.range_text} | {p.unit or ''} | {p.default} |")
    return "\n".join(rows)


def _doc(module: str) -> str:
    """A module's docstring as it reads in the code: fixed-width text."""
    return "```text\n" + inspect.cleandoc(importlib.import_module(module).__doc__ or "").rstrip() + "\n```"


def on_page_markdown(markdown: str, page, config, files) -> str:
    markdown = re.sub(r"<!-- jiggle:doc ([\w.]+) -->", lambda m: _doc(m[1]), markdown)
    if "<!-- jiggle:cli -->" in markdown:
        markdown = markdown.replace("<!-- jiggle:cli -->", _cli())
    if "<!-- jiggle:parameters -->" in markdown:
        markdown = markdown.replace("<!-- jiggle:parameters -->", _parameters())
    if "<!-- jiggle:chain-parameters -->" in markdown:
        markdown = markdown.replace("<!-- jiggle:chain-parameters -->", _chain_parameters())
    return markdown
