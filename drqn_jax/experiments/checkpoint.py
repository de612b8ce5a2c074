"""Checkpoints of a pytree: a deterministic ``NAME.npz`` (one ``.npy`` per leaf + ``manifest.json``:
``format``, ``drqn_jax_version``, ``drqn_jax_commit``, the caller's meta, ``leaves``) and
``NAME.json``, the manifest plus ``npz_sha256`` for humans (never read back). Restoration is
bit-exact (dtype, shape, bits; PRNG keys as key_data; exotic dtypes as uint of their width). Crash
safety: the npz is written to a temp file, fsynced and renamed (the commit point), then the json;
zip CRC-32s detect truncation or corruption."""

import contextlib
import hashlib
import io
import json
import os
import re
import secrets
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import drqn_jax
from drqn_jax.experiments.machine import git_commit

CHECKPOINT = "checkpoint"  # the default file stem: checkpoint.npz and checkpoint.json
CHECKPOINT_NPZ = f"{CHECKPOINT}.npz"
CHECKPOINT_JSON = f"{CHECKPOINT}.json"
AGENT = "agent"  # the stem of a trained agent's parameters alone (a sweep's OUT/agents/run-NNNN)
FORMAT = 2  # the layout this version writes and reads (its TrainState, its training hash)
_MANIFEST = "manifest.json"  # the npz entry that holds the manifest
_RESERVED = ("format", "drqn_jax_version", "drqn_jax_commit", "npz_sha256", "leaves")
_MAX_LISTED = 5  # mismatches named in one error message
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # fixed entry timestamps: deterministic bytes
_ABSENT = object()  # a field one side of a config diff lacks
#: What reading a broken archive raises (RuntimeError: an entry flagged as encrypted).
_ZIP_ERRORS = (zipfile.error, zipfile.LargeZipFile, OSError, EOFError, ValueError, RuntimeError)


class CheckpointError(ValueError):
    """A checkpoint that is missing, truncated/corrupt or incompatible; the message names what."""


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temp file, fsync, ``os.replace``, dir fsync)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError, AttributeError):  # the rename made durable (POSIX)
        fd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """:func:`atomic_write_bytes` of ``text`` encoded as UTF-8."""
    atomic_write_bytes(path, text.encode("utf-8"))


def _config_diff(saved: Any, expected: Any, prefix: str = "") -> list[str]:
    """``"a.b: checkpoint X, this run Y"`` for every differing leaf of two nested dicts."""
    if isinstance(saved, dict) and isinstance(expected, dict):
        out: list[str] = []
        for key in sorted(set(saved) | set(expected), key=str):
            name = f"{prefix}.{key}" if prefix else str(key)
            out += _config_diff(saved.get(key, _ABSENT), expected.get(key, _ABSENT), name)
        return out
    if saved == expected and type(saved) is type(expected):
        return []
    ours, theirs = (
        "<absent>" if v is _ABSENT else json.dumps(v, sort_keys=True) for v in (saved, expected)
    )
    return [f"{prefix or '<config>'}: checkpoint {ours}, this run {theirs}"]


def _json_default(value: Any) -> Any:
    """JSON for NumPy/JAX scalars and arrays in ``meta`` (``int(x)`` is not needed)."""
    if isinstance(value, np.generic | np.ndarray | jax.Array):
        return np.asarray(value).tolist()
    raise TypeError(f"checkpoint meta: {type(value).__name__} {value!r} is not JSON-serialisable")


def _shape_dtype(leaf: Any) -> tuple[tuple[int, ...], Any]:
    """Logical (shape, dtype) of an array, key array, ShapeDtypeStruct or Python scalar."""
    if not hasattr(leaf, "dtype") or not hasattr(leaf, "shape"):
        leaf = jnp.asarray(leaf)
    return tuple(int(d) for d in leaf.shape), leaf.dtype


def _encode(state: Any) -> tuple[list[dict[str, Any]], list[np.ndarray]]:
    """The manifest entries and host arrays of ``state``'s leaves, in flatten order: each
    entry named by its key path reduced to ``[A-Za-z0-9_]`` (made unique), a key array
    stored as its key data, a dtype NumPy does not know as the uint of its width."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(state)
    entries: list[dict[str, Any]] = []
    arrays: list[Any] = []
    used: set[str] = set()
    for path, leaf in leaves:
        keystr = jax.tree_util.keystr(path)
        base = re.sub(r"[^A-Za-z0-9]+", "_", keystr).strip("_") or "leaf"
        name, n = base, 1
        while name in used:
            n += 1
            name = f"{base}__{n}"
        used.add(name)
        shape, dtype = _shape_dtype(leaf)
        entry = {"name": name, "path": keystr, "shape": list(shape), "dtype": str(dtype)}
        if jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key):
            impl = jax.random.key_impl(leaf)
            entry["key_impl"] = impl if isinstance(impl, str) else str(impl)
            arrays.append(jax.random.key_data(leaf))
        else:
            arrays.append(leaf if hasattr(leaf, "dtype") else jnp.asarray(leaf))
        entries.append(entry)
    host = [np.asarray(a, order="C") for a in jax.device_get(arrays)]
    return entries, [a if a.dtype.isbuiltin == 1 else a.view(f"uint{8 * a.itemsize}") for a in host]


def save_checkpoint(
    run_dir: str | os.PathLike, state: Any, meta: dict[str, Any], *, name: str = CHECKPOINT
) -> None:
    """Save the pytree ``state`` and JSON ``meta`` as ``run_dir/NAME.npz`` (+ ``NAME.json``);
    ValueError if ``meta`` uses a ``_RESERVED`` key, TypeError if it is not JSON."""
    clash = [k for k in _RESERVED if k in meta]
    if clash:
        raise ValueError(f"checkpoint meta may not use the reserved key(s) {', '.join(clash)}")
    run_dir = Path(run_dir)
    entries, arrays = _encode(state)
    version = {
        "format": FORMAT,
        "drqn_jax_version": drqn_jax.__version__,
        "drqn_jax_commit": git_commit(),
    }
    manifest = {**version, **meta, "leaves": entries}
    text = json.dumps(manifest, indent=1, default=_json_default) + "\n"  # may raise: no write
    buffer = io.BytesIO()  # one .npy entry per leaf, then the manifest; fixed timestamps
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as zf:
        for entry, array in zip(entries, arrays, strict=True):
            info = zipfile.ZipInfo(entry["name"] + ".npy", date_time=_ZIP_TIME)
            with zf.open(info, "w", force_zip64=array.nbytes > 2**31) as f:
                np.lib.format.write_array(f, array, allow_pickle=False)
        zf.writestr(zipfile.ZipInfo(_MANIFEST, date_time=_ZIP_TIME), text.encode("utf-8"))
    data = buffer.getvalue()
    saved = json.loads(text)  # as stored: NumPy scalars and tuples already converted
    copy = {**version, "npz_sha256": hashlib.sha256(data).hexdigest(), **saved}
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(run_dir / f"{name}.npz", data)
    atomic_write_text(run_dir / f"{name}.json", json.dumps(copy, indent=1) + "\n")


def load_checkpoint(
    run_dir: str | os.PathLike,
    template: Any,
    expected_meta: dict[str, Any] | None = None,
    *,
    name: str = CHECKPOINT,
) -> tuple[Any, dict[str, Any]]:
    """``(state, meta)`` from ``run_dir/NAME.npz``, bit-identical, in ``template``'s structure:
    leaves must match ``template`` in key path, shape and dtype, ``config_hash`` must equal
    ``expected_meta``'s when both have one; else CheckpointError naming what is wrong."""
    run_dir = Path(run_dir)
    with _open(run_dir, name) as (read, manifest):
        if expected_meta is not None:
            _check_config(run_dir, manifest, expected_meta)
        leaves = []
        for entry in _check_template(run_dir, manifest["leaves"], template):
            raw = read(entry["name"] + ".npy", entry["path"])
            stored = np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)
            if entry.get("key_impl") is not None:  # bit-identical to the saved leaf
                leaves.append(jax.random.wrap_key_data(jnp.asarray(stored), impl=entry["key_impl"]))
            else:
                leaves.append(jax.device_put(stored.view(jnp.dtype(entry["dtype"]))))
    treedef = jax.tree.structure(template)
    meta = {k: v for k, v in manifest.items() if k != "leaves"}
    return jax.tree.unflatten(treedef, leaves), meta


def read_manifest(run_dir: str | os.PathLike, name: str = CHECKPOINT) -> dict[str, Any]:
    """The checked manifest of ``run_dir/NAME.npz``, its ``leaves`` included."""
    with _open(Path(run_dir), name) as (_, manifest):
        return manifest


def writer(manifest: dict[str, Any]) -> str:
    """``drqn_jax 0.1.0 at commit abc1234 in format 2``: what wrote a manifest."""
    commit = manifest.get("drqn_jax_commit")
    at = f" at commit {commit}" if commit else ""
    return f"drqn_jax {manifest.get('drqn_jax_version')}{at} in format {manifest['format']!r}"


@contextlib.contextmanager
def _open(run_dir: Path, name: str) -> Iterator[tuple[Callable[[str, str], bytes], dict]]:
    """``read(member, what)`` of the open archive ``run_dir/NAME.npz`` (an entry's bytes,
    its CRC-32 checked) and its checked manifest."""
    npz_path = run_dir / f"{name}.npz"
    if not run_dir.is_dir():
        raise CheckpointError(f"no checkpoint: directory {run_dir} does not exist")
    try:
        archive = zipfile.ZipFile(npz_path)
    except FileNotFoundError:
        raise CheckpointError(f"no checkpoint in {run_dir} (no {npz_path.name})") from None
    except (zipfile.error, zipfile.LargeZipFile, EOFError, ValueError) as err:
        raise CheckpointError(
            f"{npz_path} is not a valid npz archive (truncated or corrupt: {err})"
        ) from None
    except OSError as err:
        raise CheckpointError(f"cannot read {npz_path}: {err.strerror or err}") from None

    def read(member: str, what: str) -> bytes:
        try:
            return archive.read(member)
        except KeyError:
            raise CheckpointError(f"{npz_path} is corrupt: it has no {member} ({what})") from None
        except _ZIP_ERRORS as err:
            raise CheckpointError(
                f"{npz_path} is corrupt: cannot read {member} ({what}): {err}"
            ) from None

    with archive:
        where = f"{npz_path} ({_MANIFEST})"
        try:
            manifest = json.loads(read(_MANIFEST, "the checkpoint manifest").decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise CheckpointError(f"{where} is unreadable (truncated or corrupt: {err})") from None
        if not isinstance(manifest, dict) or "format" not in manifest:
            raise CheckpointError(f"{where} is not a checkpoint manifest (no 'format')")
        if manifest["format"] != FORMAT:
            raise CheckpointError(
                f"{npz_path}: written by {writer(manifest)}; this version reads format {FORMAT}: "
                "train it again, or use the commit that wrote it"
            )
        if not isinstance(manifest.get("leaves"), list):
            raise CheckpointError(f"{where} is corrupt: 'leaves' missing or malformed")
        yield read, manifest


def _check_config(run_dir: Path, manifest: dict[str, Any], expected: dict[str, Any]) -> None:
    """Raise unless the saved ``config_hash`` equals ``expected``'s (when it has one)."""
    saved_hash, wanted_hash = manifest.get("config_hash"), expected.get("config_hash")
    if wanted_hash is None or saved_hash == wanted_hash:
        return
    saved, wanted = manifest.get("config"), expected.get("config")
    diffs: list[str] = []
    if isinstance(saved, dict) and isinstance(wanted, dict):
        wanted = json.loads(json.dumps(wanted, default=_json_default))  # tuples → lists
        diffs = _config_diff(saved, wanted)
    if diffs:
        why = " " + _listed(diffs, "field differs", "fields differ")
    else:
        ours = str(wanted_hash)[:12]
        why = f": config_hash {str(saved_hash)[:12]}… in the checkpoint, {ours}… in this run"
    raise CheckpointError(f"checkpoint in {run_dir} was made with another configuration{why}")


def _listed(problems: list[str], one: str, many: str) -> str:
    """``(7 fields differ): a; b; c; d; e; and 2 more``."""
    more = f"; and {len(problems) - _MAX_LISTED} more" if len(problems) > _MAX_LISTED else ""
    what = f"({len(problems)} {many if len(problems) > 1 else one}): "
    return what + "; ".join(problems[:_MAX_LISTED]) + more


def _check_template(
    run_dir: Path, saved: list[dict[str, Any]], template: Any
) -> list[dict[str, Any]]:
    """The saved entries in ``template``'s leaf order; raise if any leaf does not fit."""
    by_path = {entry["path"]: entry for entry in saved}
    wanted, _ = jax.tree_util.tree_flatten_with_path(template)
    problems: list[str] = []
    entries: list[dict[str, Any]] = []
    for path, leaf in wanted:
        keystr = jax.tree_util.keystr(path)
        shape, dtype = _shape_dtype(leaf)
        entry = by_path.pop(keystr, None)
        if entry is None:
            problems.append(f"{keystr}: not in the checkpoint, expected {shape} {dtype}")
            continue
        if tuple(entry["shape"]) != shape or entry["dtype"] != str(dtype):
            saved_as = f"{tuple(entry['shape'])} {entry['dtype']}"
            problems.append(f"{keystr}: checkpoint {saved_as}, expected {shape} {dtype}")
        entries.append(entry)
    problems += [
        f"{path}: in the checkpoint ({tuple(entry['shape'])} {entry['dtype']}), not in the template"
        for path, entry in by_path.items()
    ]
    if problems:
        raise CheckpointError(
            f"checkpoint in {run_dir} does not fit the expected state "
            + _listed(problems, "leaf differs", "leaves differ")
        )
    return entries
