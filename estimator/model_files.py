"""Model data files: resolve a name in ``models/<folder>/`` or a file path, and parse its TOML.

Every data file a user can add (sensor configurations, paths, noise models, receiver
layouts) is found the same way: a bare name (no suffix, no directory part) means
``models/<folder>/<name>.toml``; anything else is a file path. Errors name the file and, for
an unknown name, list the names that exist.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

__all__ = ["MODELS_DIR", "SOURCE_CHECKOUT", "read_model_toml", "resolve_model_file"]

_ROOT = Path(__file__).resolve().parents[1]
#: Whether this code runs from a source checkout (pyproject.toml beside the packages) rather
#: than from an installed wheel; results and caches go into the checkout only in that case.
SOURCE_CHECKOUT = (_ROOT / "pyproject.toml").is_file() and (_ROOT / "models").is_dir()


def _models_dir() -> Path:
    """``models/`` of the checkout, or the installed package data ``configpose_models``
    (pyproject maps the folder to that package, so a plain ``pip install .`` ships it)."""
    if SOURCE_CHECKOUT:
        return _ROOT / "models"
    from importlib.resources import files

    return Path(str(files("configpose_models")))


MODELS_DIR = _models_dir()


def resolve_model_file(name_or_path: str | Path, folder: Path, what: str, *,
                       error: type[Exception] = ValueError, known_glob: str = "*.toml") -> Path:
    """The file for ``name_or_path``: ``folder/<name>.toml`` for a bare name, else the path.

    Raises ``error`` (a ValueError subclass of the caller's module) when the file does not
    exist, listing the known names (stems of ``folder/known_glob``).
    """
    p = Path(name_or_path)
    if not p.suffix and p.parent == Path("."):
        p = folder / f"{name_or_path}.toml"
    if not p.is_file():
        known = sorted(f.stem for f in folder.glob(known_glob))
        raise error(f"{what} {str(name_or_path)!r}: no such file {p}; known names: {known}")
    return p


def read_model_toml(name_or_path: str | Path, folder: Path, what: str, *,
                    error: type[Exception] = ValueError, known_glob: str = "*.toml"
                    ) -> tuple[dict, Path]:
    """``(table, file)``: the parsed TOML of :func:`resolve_model_file`'s file.

    Invalid TOML raises ``error`` naming the file and the parser's message (line, column).
    """
    p = resolve_model_file(name_or_path, folder, what, error=error, known_glob=known_glob)
    try:
        with open(p, "rb") as fh:
            return tomllib.load(fh), p
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{p}: not valid TOML: {exc}") from None
