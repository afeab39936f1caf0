"""On-disk cache of simulated :class:`~sim.truth.Truth` trajectories, keyed by content hash.

A sweep evaluates many estimators on the same few paths; simulating each path once and
reusing the file keeps the sweep fast (issue 3: "cache by a hash of everything that determines
it"). The key is a JSON-able dict of *everything* that determines the arrays: the model's XML
text, the sensor configuration, the path, the controller parameters, the seed, the mujoco and
numpy versions, a digest of the simulators' source files (:data:`SIMULATOR_SOURCES`, so
editing the simulator invalidates its cached truths without anyone remembering to) and a
manual salt (:data:`CODE_SALT`, for changes outside those files). Its SHA-256 over canonical
JSON names the file ``<cache_dir>/<hash>.npz``.

Concurrency: parallel sweep workers may compute the same key at once. Each writer saves to a
unique temporary file in the cache directory and ``os.replace``-s it onto the final name
(atomic on POSIX within one filesystem), so a reader only ever sees a complete file; the last
writer wins with identical content. A file that fails to load or whose stored hash differs is
recomputed and replaced, with a warning (it can only come from outside interference).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import warnings
from collections.abc import Callable
from pathlib import Path as FsPath
from typing import Any

import numpy as np

from estimator.configuration import MODELS_DIR, SensorConfig
from estimator.model_files import SOURCE_CHECKOUT
from sim.paths import Path
from sim.truth import Truth

__all__ = ["CODE_SALT", "DEFAULT_CACHE_DIR", "SIMULATOR_SOURCES", "cached", "canonical",
           "key_hash", "source_digest", "truth_key"]

#: Bump when something outside :data:`SIMULATOR_SOURCES` changes a simulator's output.
CODE_SALT = "truth-2026-11-22a"

#: The modules whose code determines a simulated Truth (their text is part of every key).
SIMULATOR_SOURCES = tuple(FsPath(__file__).resolve().parent / f for f in (
    "rover.py", "quadcopter.py", "controllers.py", "paths.py", "truth.py"))

#: ``results/cache/truth`` in a source checkout; ``~/.cache/configpose/truth`` for a wheel.
DEFAULT_CACHE_DIR = (MODELS_DIR.parent / "results" / "cache" / "truth" if SOURCE_CHECKOUT
                     else FsPath.home() / ".cache" / "configpose" / "truth")


def canonical(obj: Any) -> Any:
    """Reduce ``obj`` to plain JSON types, deterministically.

    dict keys become str (sorted on dump), tuples/arrays become lists, numpy scalars become
    Python numbers, :class:`~sim.paths.Path` and
    :class:`~estimator.configuration.SensorConfig` become their defining fields. Floats keep
    full precision (JSON writes ``repr``). Non-finite floats are rejected: they would make
    equal inputs hash unequally (NaN != NaN) or not round-trip.
    """
    if isinstance(obj, Path):
        return canonical(obj.to_dict())
    if isinstance(obj, SensorConfig):
        return canonical({
            "names": list(obj.names), "body_positions": obj.body_positions,
            "cg_members": list(obj.cg_members), "dead": list(obj.dead),
            "mount_height_m": obj.mount_height_m, "name": obj.name,
        })
    if isinstance(obj, dict):
        return {str(k): canonical(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [canonical(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return canonical(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        if not math.isfinite(v):
            raise ValueError(f"cache key: non-finite number {v!r} cannot be hashed reliably")
        return v
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, FsPath):
        return str(obj)
    raise ValueError(f"cache key: cannot canonicalise value of type {type(obj).__name__}: {obj!r}")


@functools.cache
def source_digest(files: tuple[FsPath, ...]) -> str:
    """SHA-256 (hex) over the names and bytes of ``files``: changes when any of them does.

    Cached per process (the files are read once).
    """
    h = hashlib.sha256()
    for f in sorted(FsPath(f) for f in files):
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def key_hash(key: dict) -> str:
    """SHA-256 (first 24 hex digits) of the canonical JSON of ``key``."""
    text = json.dumps(canonical(key), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def truth_key(*, simulator: str, model_xml: str, path: Path, params: dict, seed: int,
              config: SensorConfig | None = None) -> dict:
    """The cache key of a simulated Truth: everything that determines its arrays.

    simulator : "rover" | "quadcopter" | ..., the producing function.
    model_xml : the full MJCF text actually compiled (after any generated edits).
    path : the path followed. params : controller/simulation parameters (JSON-able).
    seed : the run's seed. config : the sensor configuration (None when fixed by the model).
    Versions of mujoco and numpy, the digest of :data:`SIMULATOR_SOURCES` and
    :data:`CODE_SALT` are added here.
    """
    import mujoco

    return canonical({
        "simulator": simulator,
        "model_xml_sha256": hashlib.sha256(model_xml.encode()).hexdigest(),
        "config": config, "path": path, "params": params, "seed": int(seed),
        "versions": {"mujoco": mujoco.__version__, "numpy": np.__version__},
        "code_salt": CODE_SALT,
        "code_sha256": source_digest(SIMULATOR_SOURCES),
    })


def cached(key: dict, compute: Callable[[], Truth], cache_dir: str | os.PathLike | None = None
           ) -> Truth:
    """Return the Truth stored under ``key_hash(key)``, computing and storing it if absent.

    ``cache_dir`` defaults to :data:`DEFAULT_CACHE_DIR`. The returned Truth's ``meta`` carries
    ``hash`` (the file's hash) and ``cache_key`` (the key). Safe under concurrent callers
    (see the module docstring).
    """
    h = key_hash(key)
    cache_dir = FsPath(cache_dir) if cache_dir is not None else DEFAULT_CACHE_DIR
    final = cache_dir / f"{h}.npz"
    if final.is_file():
        try:
            truth = Truth.load(final)
            if truth.meta.get("hash") == h:
                return truth
            reason = f"stored hash {truth.meta.get('hash')!r} differs"
        except Exception as exc:  # noqa: BLE001 - any unreadable file is recomputed, loudly
            reason = f"{type(exc).__name__}: {exc}"
        warnings.warn(f"truth cache: {final} is unusable ({reason}); recomputing", stacklevel=2)
    truth = compute()
    if not isinstance(truth, Truth):
        raise TypeError(f"compute: must return a Truth, got {type(truth).__name__}")
    truth = dataclasses.replace(truth, meta={**truth.meta, "hash": h, "cache_key": canonical(key)})
    truth.save(final)  # atomic (sim.atomic): concurrent writers never share a temp file
    return truth
