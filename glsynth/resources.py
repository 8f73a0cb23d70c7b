"""Locate data shipped with glsynth (GLSL shaders, YAML configs).

In a source checkout or editable install they sit at the repository root
(``shaders/``, ``configs/``); a wheel carries them inside the package (pyproject.toml
maps them to ``glsynth/shaders`` and ``glsynth/configs``).
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

_PKG = Path(__file__).resolve().parent


def _find(kind: str) -> Path:
    for cand in (_PKG / kind, _PKG.parent / kind):
        if cand.is_dir():
            return cand
    raise FileNotFoundError(f"glsynth's {kind}/ folder is neither in {_PKG} (an installed wheel) "
                            f"nor in {_PKG.parent} (a source checkout); reinstall glsynth")


def shader_dir() -> Path:
    return _find("shaders")


def config_dir() -> Path:
    return _find("configs")


@lru_cache(maxsize=None)
def shader_source(name: str) -> str:
    """GLSL source with ``#include "file"`` lines replaced by that file's source."""
    path = shader_dir() / name
    if not path.is_file():
        raise FileNotFoundError(f"shader {name!r} not found in {shader_dir()}")
    lines = []
    for line in path.read_text().splitlines():
        if line.startswith("#include "):
            lines.append(shader_source(line.split(None, 1)[1].strip().strip('"')))
        else:
            lines.append(line)
    return "\n".join(lines) + "\n"


def with_defines(source: str, **defines) -> str:
    """``source`` with ``#define NAME value`` lines inserted after its #version line."""
    head, _, rest = source.partition("\n")
    if not head.startswith("#version"):
        raise ValueError("shader source must start with a #version line")
    lines = "".join(f"#define {k} {int(v) if isinstance(v, bool) else v}\n" for k, v in defines.items())
    return f"{head}\n{lines}{rest}"
