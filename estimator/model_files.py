"""Model data files: resolve a name in ``models/<folder>/`` or a file path, and parse its TOML.

Every data file a user can add (sensor configurations, paths, noise models, receiver
layouts, recordings, sessions, logs) is found by one function with one rule,
:func:`resolve_model_file` (issue 24):

- a bare name (no suffix, no directory part) means ``<folder>/<name>.toml`` when the kind
  of file has a folder in ``models/``;
- a path given directly by the user (a CLI argument, ``SensorConfig.load(path)``, a spec
  built in Python by ``Spec.from_dict`` without ``base_dir``) is taken as given (relative
  to the working directory, then the project);
- a path named *inside* a file (a spec, a recording: ``base`` is that file's folder) is
  tried against ``base``, then the project, and must resolve (symbolic links followed) to a
  file inside ``base``, the project or the shared data folder beside the project
  (``../shared``, where the real logs live): ``../../../../etc/passwd`` or ``/etc/hostname``
  in a spec or a recording is an error, so a spec or recording shared with others reads
  only files that come with it or with the project.

Errors name the field and the value and, for an unknown name, list the names that exist.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

__all__ = ["ALLOWED_ROOTS", "MODELS_DIR", "PROJECT_DIR", "SHARED_DIR", "SOURCE_CHECKOUT",
           "parse_toml", "read_model_toml", "resolve_model_file"]

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
#: The project: the checkout, or the folder holding the installed package data.
PROJECT_DIR = _ROOT if SOURCE_CHECKOUT else MODELS_DIR.parent
#: The shared data beside a checkout (``../shared/realdata``: real receiver logs the
#: shipped recordings name); None for an installed wheel.
SHARED_DIR = _ROOT.parent / "shared" if SOURCE_CHECKOUT else None
#: Where a file named inside a spec or recording may resolve to, besides that file's folder.
ALLOWED_ROOTS = tuple(r.resolve() for r in (PROJECT_DIR, SHARED_DIR) if r is not None)


def resolve_model_file(name_or_path: str | Path, folder: Path | None, what: str, *,
                       base: Path | None = None, error: type[Exception] = ValueError,
                       known_glob: str = "*.toml") -> Path:
    """The file for ``name_or_path`` under the module's one rule (module docstring).

    folder : ``models/<kind>`` for a bare name, or None (the kind has no folder: logs,
    sessions); base : the folder of the file naming it (spec, recording), None for a path
    the user gave directly; what : the field, for messages. Returns the path (resolved,
    symbolic links followed, when named inside a file).
    Raises ``error`` (the caller's ValueError subclass) naming ``what`` and the value: not a
    string, unknown name (listing the known ones), no such file, or outside the allowed
    folders.
    """
    if not isinstance(name_or_path, (str, Path)) or not str(name_or_path):
        raise error(f"{what}: must be a file name or path (string), got {name_or_path!r}")
    value = str(name_or_path)
    p = Path(value)
    if folder is not None and not p.suffix and p.parent == Path(".") and "\\" not in value:
        cand = folder / f"{value}.toml"
        if not cand.is_file():
            known = sorted(f.stem for f in folder.glob(known_glob))
            raise error(f"{what}: unknown name {value!r} (no such file {cand}); known names: "
                        f"{known}; add the file or give a file path")
        return cand
    if base is None:
        for cand in (p, PROJECT_DIR / p):
            if cand.is_file():
                return cand
        raise error(f"{what}: no such file {value!r}")
    return _inside_roots(p, Path(base).resolve(), what, error)


def _inside_roots(p: Path, base: Path, what: str, error: type[Exception]) -> Path:
    """A path named inside a file in ``base``: the first existing candidate (``base / p``,
    then ``PROJECT_DIR / p``) that lies inside ``base`` or :data:`ALLOWED_ROOTS`."""
    roots = (base, *ALLOWED_ROOTS)
    cands = ([p.resolve()] if p.is_absolute()
             else [(base / p).resolve(), (PROJECT_DIR / p).resolve()])
    outside = []
    for c in cands:
        if c.is_file():
            if any(c.is_relative_to(r) for r in roots):
                return c
            outside.append(c)
    if outside or not any(c.is_relative_to(r) for c in cands for r in roots):
        where = ", ".join(str(r) for r in roots)
        raise error(f"{what}: {str(p)!r} leaves the folder of the file naming it and the "
                    f"project ({where}); copy the file there and name it relative to "
                    f"that file")
    raise error(f"{what}: no such file {str(p)!r} (looked in {base} and {PROJECT_DIR})")


def read_model_toml(name_or_path: str | Path, folder: Path, what: str, *,
                    error: type[Exception] = ValueError, known_glob: str = "*.toml"
                    ) -> tuple[dict, Path]:
    """``(table, file)``: the parsed TOML of :func:`resolve_model_file`'s file.

    Invalid TOML raises ``error`` naming the file and the parser's message (line, column).
    """
    p = resolve_model_file(name_or_path, folder, what, error=error, known_glob=known_glob)
    with open(p, "rb") as fh:
        return parse_toml(fh.read(), p, error=error), p


def parse_toml(data: bytes | str, path: Path | str, *, error: type[Exception] = ValueError
               ) -> dict:
    """The TOML table of ``data`` (the contents of ``path``); one-line ``error`` naming the
    file for text that is not UTF-8, not TOML, or nested too deeply for the parser
    (tomllib recurses per level: a 3,000-deep array exhausts Python's stack)."""
    try:
        text = data.decode("utf-8") if isinstance(data, bytes) else data
        return tomllib.loads(text)
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start}: "
                    f"{exc.object[exc.start:exc.start + 1]!r}); expected a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML: {exc}") from None
    except RecursionError:
        raise error(f"{path}: not usable TOML: arrays or tables nested too deeply for the "
                    f"parser (the files of this project nest a few levels)") from None
