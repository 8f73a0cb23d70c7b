"""The config's keys as text, generated from their declarations in glsynth/config.py:
the key table of docs/config.md and the full default config, configs/default.yaml.

    python -m glsynth.configdoc --doc  > docs/config.md
    python -m glsynth.configdoc --yaml > configs/default.yaml

Both files are checked against these functions by the tests, so they always say what
``Config()`` is.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import textwrap

import yaml

from .config import Config, keys, section_type

_HOW = "python -m glsynth.configdoc"


def value_text(value) -> str:
    """``value`` as one line of YAML (flow style)."""
    text = yaml.safe_dump(value, default_flow_style=True, sort_keys=False, width=math.inf)
    return text.removesuffix("\n...\n").strip()


def _sections():
    """(name, dataclass) of Config's sections, in declaration order."""
    return [(f.name, section_type(f)) for f in dataclasses.fields(Config) if section_type(f)]


def markdown() -> str:
    """docs/config.md: every key's default, accepted values and meaning, by section."""
    out = [
        "# Configuration keys",
        "",
        f"Generated from `glsynth/config.py` by `{_HOW} --doc`;",
        "do not edit (a test checks it).",
        "",
        "A config file (YAML) lists only the keys it changes: every other key keeps its default",
        "below, which together make glsynth's default run (`configs/default.yaml` lists them",
        "all). `configs/paper.yaml` is the DermSynth3D paper's preset (`docs/paper.md`). On the",
        "command line, `--set key.sub=value` overrides one key (the value is read as YAML).",
        "Ranges are `[low, high]` lists from which each body, lesion or view draws a value.",
        "",
    ]

    def table(rows):
        out.extend(["| key | default | accepts | meaning |", "|---|---|---|---|"])
        for name, f in rows:
            accepts = f.metadata["accepts"].describe()
            out.append(f"| `{name}` | `{value_text(_default(f))}` | {_cell(accepts)} | "
                       f"{_cell(f.metadata['doc'])} |")
        out.append("")

    top = [(n, f) for n, f in keys() if "." not in n]
    out.extend(["## Top level", "", Config.__doc__.strip(), ""])
    table(top)
    for name, section in _sections():
        out.extend([f"## {name}", "", " ".join(section.__doc__.split()), ""])
        table(keys(section, f"{name}."))
    return "\n".join(out)


def default_yaml() -> str:
    """configs/default.yaml: every key with its default, its meaning as a comment."""
    out = [
        "# glsynth's default configuration: the value of every key a config file leaves out.",
        f"# Generated from glsynth/config.py by `{_HOW} --yaml`;",
        "# do not edit (a test checks it): change the defaults there. docs/config.md says",
        "# what each key accepts. Copy the keys you want to change into a config of your own.",
    ]

    def entries(rows, indent):
        for name, f in rows:
            out.extend(_comment(f.metadata["doc"], indent))
            out.append(f"{indent}{name.rsplit('.', 1)[-1]}: {value_text(_default(f))}")

    entries([(n, f) for n, f in keys() if "." not in n and n != "outputs"], "")
    for name, section in _sections():
        out.append("")
        out.extend(_comment(section.__doc__, ""))
        out.append(f"{name}:")
        entries(keys(section, f"{name}."), "  ")
    out.append("")
    entries([(n, f) for n, f in keys() if n == "outputs"], "")
    return "\n".join(out) + "\n"


def _default(f):
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def _comment(text: str, indent: str) -> list:
    return textwrap.wrap(" ".join(text.split()), width=90, initial_indent=f"{indent}# ",
                         subsequent_indent=f"{indent}# ")


def main(argv=None):
    ap = argparse.ArgumentParser(prog=_HOW, description=__doc__.splitlines()[0])
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--doc", action="store_true", help="print docs/config.md")
    what.add_argument("--yaml", action="store_true", help="print configs/default.yaml")
    args = ap.parse_args(argv)
    sys.stdout.write(markdown() if args.doc else default_yaml())


if __name__ == "__main__":
    main()
