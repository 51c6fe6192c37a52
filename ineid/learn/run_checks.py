"""Reading a run folder's files defensively: a damaged file is one :class:`TrainingError` line.

A run folder (:mod:`ineid.learn.runs`) is written by ineid atomically, but a disk, a copy
or a hand edit can still damage it. Every reader here checks what it reads (JSON that
parses, the keys and types :func:`ineid.learn.train.train` wrote, msgpack that restores
into the network) and names the file, what is wrong with it and the fix, instead of the
``JSONDecodeError``, ``KeyError`` or msgpack ``ValueError`` deep in a traceback.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ineid import _inputs
from ineid.errors import TrainingError
from ineid.learn.config import TrainConfig
from ineid.learn.data import Split
from ineid.learn.scalers import SCALERS, Scaler

FIX = "train the run again (ineid train ... --overwrite) or restore the file from a copy"
# What deserializing damaged msgpack raises (msgpack's own errors are ValueErrors; a
# structure that does not match the template is a ValueError, KeyError or TypeError in flax).
DECODE_ERRORS = (ValueError, KeyError, TypeError, IndexError, AttributeError, OverflowError)


def damaged(path: Path, what: str) -> TrainingError:
    """The one error of a damaged run file: its path, what is wrong, the fix."""
    return TrainingError(f"{path} is damaged ({what}); {FIX}")


def read_json(path: Path):
    """The JSON value in ``path`` (a regular file, bounded as :func:`ineid._inputs.read_json` bounds it).

    Raises:
        TrainingError: it is not UTF-8 JSON, or is too large or nested too deep for ineid.
        InputFileError: it is not a regular file (a FIFO, a folder).
    """
    try:
        return _inputs.read_json(path, "the run file")
    except UnicodeDecodeError:
        raise damaged(path, "not text") from None
    except json.JSONDecodeError as e:
        what = "empty" if not e.doc.strip() else f"not JSON: {e.msg} at line {e.lineno}, column {e.colno}"
        raise damaged(path, what) from None
    except ValueError as e:  # nested too deep
        raise damaged(path, f"JSON {e}") from None


def _int_array(value, path: Path, key: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim != 1 or (arr.size and (arr.dtype.kind not in "iu" or arr.min() < 0)):
        raise damaged(path, f"{key} is not a list of configuration indices")
    return arr.astype(np.int64)


def _numbers(value, path: Path, key: str, n: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise damaged(path, f"{key} is not a list of numbers") from None
    if arr.ndim != 1 or (n is not None and arr.size != n) or not np.all(np.isfinite(arr)):
        raise damaged(path, f"{key} is not a list of {n or 'some'} finite numbers")
    return arr


_CONFIG_KEYS = {"train": dict, "split": dict, "dataset": dict, "n_out": int, "param_names": list, "wrench_scale": list}


def read_config(run_dir: Path) -> tuple[dict, object, Split]:
    """``config.json`` of a run: ``(meta, TrainConfig, Split)``, every field :func:`train` wrote checked.

    Raises:
        TrainingError: the file is not JSON, lacks a key, or holds a value of the wrong
            type (settings that no longer build a network, a split that is not indices).
    """
    path = run_dir / "config.json"
    meta = read_json(path)
    if not isinstance(meta, dict):
        raise damaged(path, f"a JSON {type(meta).__name__}, not an object")
    bad = [k for k, t in _CONFIG_KEYS.items() if not isinstance(meta.get(k), t) or isinstance(meta.get(k), bool)]
    if bad:
        raise damaged(path, f"{', '.join(bad)} missing or of the wrong type")
    try:
        cfg = TrainConfig.from_dict(meta["train"])
    except DECODE_ERRORS as e:
        raise damaged(path, f"its training settings do not parse: {e}") from None
    if meta["n_out"] != len(meta["param_names"]) or meta["n_out"] < 1:
        raise damaged(path, f"n_out {meta['n_out']} does not match its {len(meta['param_names'])} parameter names")
    split = meta["split"]
    if set(split) != {"train", "val", "test"}:
        raise damaged(path, "split needs exactly train, val and test")
    split = Split(*(_int_array(split[k], path, f"split.{k}") for k in ("train", "val", "test")))
    n_configs = meta["dataset"].get("n_configs")
    if isinstance(n_configs, int) and any(
        a.size and a.max() >= n_configs for a in (split.train, split.val, split.test)
    ):
        raise damaged(path, f"its split names configurations beyond the dataset's {n_configs}")
    _numbers(meta["wrench_scale"], path, "wrench_scale")
    if cfg.model.uses_regressor:
        from ineid.learn.wls import WlsContext

        try:
            WlsContext.from_dict(meta["wls"])
        except DECODE_ERRORS as e:
            raise damaged(path, f"the wls constants do not parse: {type(e).__name__} {e}") from None
    return meta, cfg, split


def read_scalers(run_dir: Path) -> tuple[Scaler, Scaler]:
    """``scalers.json`` of a run: the feature and target :class:`Scaler`, checked."""
    path = run_dir / "scalers.json"
    doc = read_json(path)
    if not isinstance(doc, dict) or not all(isinstance(doc.get(k), dict) for k in ("x", "y")):
        raise damaged(path, "it needs the objects x and y")
    out = []
    for k in ("x", "y"):
        d = doc[k]
        if d.get("kind") not in SCALERS:
            raise damaged(path, f"{k}.kind must be one of {', '.join(SCALERS)}")
        center = _numbers(d.get("center"), path, f"{k}.center")
        scale = _numbers(d.get("scale"), path, f"{k}.scale", center.size)
        if not np.all(scale > 0):
            raise damaged(path, f"{k}.scale holds a number <= 0")
        out.append(Scaler(d["kind"], center, scale))
    return out[0], out[1]


def read_msgpack(path: Path, template):
    """``path`` (msgpack from flax) restored into the structure of ``template``.

    Raises:
        TrainingError: truncated or corrupt bytes, or parameters of another network.
    """
    from flax import serialization

    data = _inputs.regular_file(path, "the run file").read_bytes()
    if not data:
        raise damaged(path, "empty")
    try:
        return serialization.from_bytes(template, data)
    except DECODE_ERRORS as e:
        text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise damaged(path, f"truncated, corrupt or of another network: {text}") from None


def check_state(path: Path, state: dict, epochs: int) -> dict:
    """A restored checkpoint whose counters make sense (``0 <= epoch <= epochs``, a number as best value)."""
    try:
        epoch, best_epoch = int(state["epoch"]), int(state["best_epoch"])
        best_val, bad = float(state["best_val"]), int(state["bad_epochs"])
    except DECODE_ERRORS:
        raise damaged(path, "its counters are not numbers") from None
    if not (0 <= epoch <= epochs and 0 <= best_epoch <= epoch and bad >= 0) or math.isnan(best_val):
        raise damaged(path, f"its counters are out of range (epoch {epoch} of {epochs}, best at {best_epoch})")
    return state


def read_metrics(path: Path, keep_through_epoch: int) -> list[str]:
    """The lines of ``metrics.jsonl`` up to ``keep_through_epoch``; each must be a JSON record with an epoch."""
    lines = []
    try:
        text = _inputs.regular_file(path, "the run file").read_text()
    except UnicodeDecodeError:
        raise damaged(path, "not text") from None
    for k, line in enumerate(text.splitlines(), 1):
        if not line:
            continue
        try:
            record = _inputs.parse_json(line)
            epoch = int(record["epoch"])
        except (json.JSONDecodeError, *DECODE_ERRORS):
            raise damaged(path, f"line {k} is not a JSON record with an epoch") from None
        if epoch <= keep_through_epoch:
            lines.append(line)
    return lines
