"""Checkpoints: bit-exact round trip, resume ≡ uninterrupted, and every refusal's message."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drqn_jax.experiments.checkpoint as checkpoint_module
from drqn_jax.config import ConfigError, config_hash, load_config
from drqn_jax.experiments.checkpoint import (
    AGENT,
    CHECKPOINT_JSON,
    CHECKPOINT_NPZ,
    FORMAT,
    CheckpointError,
    atomic_write_bytes,
    atomic_write_text,
    load_checkpoint,
    save_checkpoint,
)
from drqn_jax.experiments.machine import git_commit
from drqn_jax.experiments.runner import load_run
from drqn_jax.learners import Hyperparams, make_train
from tests.helpers import assert_tree_equal, fast_jit, tiny_train_config

# short episodes, so that 5 iterations already complete one and take gradient steps
TINY = tiny_train_config(
    max_steps=3, num_episodes=8, hyperparams=Hyperparams(learning_starts=1, target_period=2)
)
CONFIG = {"train": {"batch_size": 4, "num_envs": 2, "window": 4}, "env": {"max_steps": 3}}


def is_key(x) -> bool:
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def assert_state_equal(a, b) -> None:
    """Bitwise equality of two pytrees whose leaves may be typed PRNG keys."""
    key_dtypes = [str(x.dtype) for x in jax.tree.leaves(a) if is_key(x)]
    assert key_dtypes == [str(x.dtype) for x in jax.tree.leaves(b) if is_key(x)]

    def unkey(x):
        return jax.random.key_data(x) if is_key(x) else x

    assert_tree_equal(jax.tree.map(unkey, a), jax.tree.map(unkey, b))


def meta_of(state, config=CONFIG) -> dict:
    return {
        "config": config,
        "config_hash": config_hash(config),
        "recorded": int(state.recorded),
        "grad_steps": int(state.grad_steps),
        "env_steps": int(state.env_steps),
        "chunks": 1,
        "wall_time_s": 1.5,
    }


def read_manifest(npz) -> dict:
    """The manifest embedded in a checkpoint npz."""
    with zipfile.ZipFile(npz) as zf:
        return json.loads(zf.read("manifest.json"))


def rewrite_manifest(npz, text: str) -> None:
    """Replace the npz's manifest.json entry by ``text`` (a well-formed archive, valid CRCs)."""
    with zipfile.ZipFile(npz) as zf:
        entries = [(info, zf.read(info)) for info in zf.infolist()]
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as zf:
        for info, data in entries:
            zf.writestr(info, text if info.filename == "manifest.json" else data)
    npz.write_bytes(buffer.getvalue())


@pytest.fixture(scope="module")
def tiny():
    """The trainer, its jitted run, the state after init and after 5 iterations."""
    trainer = make_train(TINY)
    # every comparison below is between runs of this one program (tests.helpers.FAST_COMPILE)
    run = fast_jit(trainer.run, static_argnums=1)
    state0 = fast_jit(trainer.init)(jax.random.key(0))
    state5 = run(state0, 5)
    assert int(state5.grad_steps) > 0 and int(state5.recorded) > 0  # a non-trivial state
    return trainer, run, state0, state5


@pytest.fixture(scope="module")
def template(tiny):
    trainer = tiny[0]
    return jax.eval_shape(trainer.init, jax.random.key(0))


def test_round_trip_bit_exact(tmp_path, tiny, template):
    _, _, state0, state5 = tiny
    meta = meta_of(state5)
    save_checkpoint(tmp_path, state5, meta)
    assert sorted(os.listdir(tmp_path)) == [CHECKPOINT_JSON, CHECKPOINT_NPZ]

    for tmpl in (template, state0):  # ShapeDtypeStructs or concrete arrays
        loaded, loaded_meta = load_checkpoint(tmp_path, tmpl, expected_meta=meta)
        assert_state_equal(loaded, state5)
        assert jax.dtypes.issubdtype(loaded.key.dtype, jax.dtypes.prng_key)
        assert np.array_equal(jax.random.key_data(loaded.key), jax.random.key_data(state5.key))
        assert {k: loaded_meta[k] for k in meta} == meta

    # the npz holds the manifest; the json is a copy of it plus the npz's SHA-256
    manifest = read_manifest(tmp_path / CHECKPOINT_NPZ)
    assert manifest["format"] == FORMAT == 2 and manifest["drqn_jax_version"]
    assert manifest["drqn_jax_commit"] == git_commit()  # what wrote it
    assert {k: v for k, v in manifest.items() if k != "leaves"} == loaded_meta
    copy = json.loads((tmp_path / CHECKPOINT_JSON).read_text())
    npz_bytes = (tmp_path / CHECKPOINT_NPZ).read_bytes()
    assert copy.pop("npz_sha256") == hashlib.sha256(npz_bytes).hexdigest()
    assert copy == manifest
    leaves = manifest["leaves"]
    assert len(leaves) == len(jax.tree.leaves(state5))
    assert len({leaf["name"] for leaf in leaves}) == len(leaves)
    key_leaf = next(leaf for leaf in leaves if leaf["path"] == ".key")
    assert key_leaf["dtype"] == "key<fry>" and key_leaf["key_impl"] == "threefry2x32"
    assert key_leaf["shape"] == []

    # the same state gives the same bytes
    first = (tmp_path / CHECKPOINT_NPZ).read_bytes()
    save_checkpoint(tmp_path, state5, meta)
    assert (tmp_path / CHECKPOINT_NPZ).read_bytes() == first

    with pytest.raises(ValueError, match=r"reserved key.*leaves"):
        save_checkpoint(tmp_path, state5, {"leaves": []})


def test_round_trip_special_leaves(tmp_path):
    """NaN payloads, −0, ∞, bfloat16, int8, batched keys, odd dict keys, Python scalars."""
    nan_payload = np.array([0x7FC00001, 0xFFC00000], np.uint32).view(np.float32)
    state = {
        "floats": jnp.concatenate([jnp.asarray(nan_payload), jnp.array([-0.0, jnp.inf])]),
        "bf16": jnp.arange(5, dtype=jnp.bfloat16) / 3,
        "small": (jnp.int8(-3), jnp.zeros((0, 2), jnp.uint16)),
        "keys": jax.random.split(jax.random.key(1), (2, 3)),
        "rbg": jax.random.key(2, impl="rbg"),
        "a/b": jnp.ones(2, bool),
        "a_b": 3.5,
    }
    save_checkpoint(tmp_path, state, {})
    loaded, meta = load_checkpoint(tmp_path, jax.eval_shape(lambda: state))
    assert meta["format"] == FORMAT
    assert_state_equal(loaded, {**state, "a_b": jnp.float32(3.5)})
    assert np.array_equal(
        np.asarray(loaded["floats"]).view(np.uint32)[:2], nan_payload.view(np.uint32)
    )


def test_resumed_run_equals_uninterrupted(tmp_path, tiny, template):
    """init, 5 iterations, save, load into an eval_shape template, 5 more ≡ 5 + 5 straight.

    The uninterrupted run reuses the compiled 5-iteration program (a 10-iteration
    one would add 7 s of compilation); that 5 + 5 iterations equal 10 in one call
    is tests/learners/dqn/test_train.py::test_chunked_equals_one_shot.
    """
    _, run, _, state5 = tiny
    save_checkpoint(tmp_path, state5, meta_of(state5))
    resumed, _ = load_checkpoint(tmp_path, template)
    straight = run(state5, 5)
    assert int(straight.grad_steps) > int(state5.grad_steps)
    assert_state_equal(run(resumed, 5), straight)


def test_missing_checkpoint(tmp_path, tiny, template):
    state5 = tiny[3]
    with pytest.raises(CheckpointError, match=r"no checkpoint: directory .*nowhere does not exist"):
        load_checkpoint(tmp_path / "nowhere", template)
    with pytest.raises(CheckpointError, match=r"no checkpoint in .*\(no checkpoint\.npz\)$"):
        load_checkpoint(tmp_path, template)
    save_checkpoint(tmp_path, state5, {})
    (tmp_path / CHECKPOINT_NPZ).unlink()  # the json alone is no checkpoint
    with pytest.raises(CheckpointError, match=r"no checkpoint in .*\(no checkpoint\.npz\)$"):
        load_checkpoint(tmp_path, template)


def test_truncated_files(tmp_path, tiny, template):
    state5 = tiny[3]
    save_checkpoint(tmp_path, state5, {})
    npz = tmp_path / CHECKPOINT_NPZ
    data = npz.read_bytes()
    npz.write_bytes(data[: len(data) // 2])
    with pytest.raises(
        CheckpointError, match=r"checkpoint\.npz is not a valid npz archive \(truncated or corrupt"
    ):
        load_checkpoint(tmp_path, template)

    save_checkpoint(tmp_path, state5, {})
    text = json.dumps(read_manifest(npz))
    rewrite_manifest(npz, text[: len(text) // 2])
    with pytest.raises(
        CheckpointError, match=r"checkpoint\.npz \(manifest\.json\) is unreadable \(truncated"
    ):
        load_checkpoint(tmp_path, template)


def test_flipped_byte_fails_the_crc(tmp_path, tiny, template):
    """A changed byte inside an entry (array data or manifest) is caught by its CRC-32."""
    save_checkpoint(tmp_path, tiny[3], {})
    npz = tmp_path / CHECKPOINT_NPZ
    good = npz.read_bytes()
    with zipfile.ZipFile(npz) as zf:
        infos = {info.filename: info for info in zf.infolist()}
    array = max(
        (i for i in infos.values() if i.filename.endswith(".npy")), key=lambda i: i.file_size
    )
    for info, error in (
        (array, rf"checkpoint\.npz is corrupt: cannot read {array.filename} \(.+\): Bad CRC-32"),
        (infos["manifest.json"], r"checkpoint\.npz is corrupt: cannot read manifest\.json .*CRC"),
    ):
        # the entry's data: after its 30-byte local header, name and extra field
        name_len, extra_len = np.frombuffer(good, "<u2", 2, info.header_offset + 26)
        start = info.header_offset + 30 + int(name_len) + int(extra_len)
        corrupt = bytearray(good)
        corrupt[start + info.file_size - 1] ^= 0x01  # the entry's last byte
        npz.write_bytes(bytes(corrupt))
        with pytest.raises(CheckpointError, match=error):
            load_checkpoint(tmp_path, template)


def test_stale_or_missing_json_is_ignored(tmp_path, tiny, template):
    """The json is a copy for people and tools; loading reads the npz alone."""
    _, _, state0, state5 = tiny
    save_checkpoint(tmp_path, state0, meta_of(state0))
    old_json = (tmp_path / CHECKPOINT_JSON).read_text()
    save_checkpoint(tmp_path, state5, meta_of(state5))
    (tmp_path / CHECKPOINT_JSON).write_text(old_json)  # stale: one save behind
    for _ in ("stale", "missing"):
        loaded, meta = load_checkpoint(tmp_path, template, meta_of(state5))
        assert_state_equal(loaded, state5)
        assert meta["recorded"] == int(state5.recorded) != int(state0.recorded)
        (tmp_path / CHECKPOINT_JSON).unlink(missing_ok=True)


def _raise(*args, **kwargs):
    raise KeyboardInterrupt("simulated crash")


def test_crash_between_the_renames_loads_the_new_checkpoint(tmp_path, tiny, template, monkeypatch):
    """B's npz is renamed in, then the process dies before B's json: load returns B."""
    _, _, state_a, state_b = tiny
    save_checkpoint(tmp_path, state_a, meta_of(state_a))
    json_a = (tmp_path / CHECKPOINT_JSON).read_text()
    monkeypatch.setattr(checkpoint_module, "atomic_write_text", _raise)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(tmp_path, state_b, meta_of(state_b))
    monkeypatch.undo()
    assert (tmp_path / CHECKPOINT_JSON).read_text() == json_a  # the json lags one save
    loaded, meta = load_checkpoint(tmp_path, template, meta_of(state_b))
    assert_state_equal(loaded, state_b)  # all of B, no leaf of A
    writer = {k: meta[k] for k in ("drqn_jax_version", "drqn_jax_commit")}
    assert meta == {**meta_of(state_b), "format": FORMAT, **writer}


def test_crash_before_the_npz_rename_keeps_the_old_checkpoint(
    tmp_path, tiny, template, monkeypatch
):
    """The process dies before B's npz is renamed in (or while it is written): load returns A."""
    _, _, state_a, state_b = tiny
    save_checkpoint(tmp_path, state_a, meta_of(state_a))
    files_a = {name: (tmp_path / name).read_bytes() for name in os.listdir(tmp_path)}
    monkeypatch.setattr(os, "replace", _raise)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(tmp_path, state_b, meta_of(state_b))
    monkeypatch.undo()
    assert {name: (tmp_path / name).read_bytes() for name in os.listdir(tmp_path)} == files_a
    # a process killed outright leaves its half-written temporary file, which is not read
    save_checkpoint(tmp_path / "b", state_b, meta_of(state_b))
    half = (tmp_path / "b" / CHECKPOINT_NPZ).read_bytes()
    (tmp_path / f".{CHECKPOINT_NPZ}.0123456789ab.tmp").write_bytes(half[: len(half) // 2])
    loaded, meta = load_checkpoint(tmp_path, template, meta_of(state_a))
    assert_state_equal(loaded, state_a)
    assert meta["recorded"] == int(state_a.recorded)


def test_another_format_is_refused_naming_what_wrote_it(tmp_path, tiny, template):
    """A checkpoint of the previous layout (format 1: no commit recorded) or of a later
    one is refused in one line: the version, commit and format that wrote it, and what
    to do; this version reads no other layout."""
    save_checkpoint(tmp_path, tiny[3], {})
    npz = tmp_path / CHECKPOINT_NPZ
    manifest = read_manifest(npz)
    old = {k: v for k, v in manifest.items() if k != "drqn_jax_commit"}
    rewrite_manifest(npz, json.dumps({**old, "format": 1, "drqn_jax_version": "0.1.0"}))
    with pytest.raises(
        CheckpointError,
        match=r"checkpoint\.npz: written by drqn_jax 0\.1\.0 in format 1; this version reads "
        r"format 2: train it again, or use the commit that wrote it$",
    ):
        load_checkpoint(tmp_path, template)
    later = {**manifest, "format": 3, "drqn_jax_commit": "abc1234"}
    rewrite_manifest(npz, json.dumps(later))
    with pytest.raises(CheckpointError, match=r"at commit abc1234 in format 3; this version"):
        load_checkpoint(tmp_path, template)


def _old_run_dir(directory, tiny, config_toml: str, manifest_changes: dict) -> None:
    """A run directory: ``config_toml`` and a checkpoint whose manifest is changed so
    (a key changed to None is dropped)."""
    directory.mkdir()
    (directory / "config.toml").write_text(config_toml)
    save_checkpoint(directory, tiny[3], {})
    npz = directory / CHECKPOINT_NPZ
    manifest = {**read_manifest(npz), **manifest_changes}
    rewrite_manifest(npz, json.dumps({k: v for k, v in manifest.items() if v is not None}))


def test_a_run_directory_of_another_version_is_refused_in_one_line(tmp_path, tiny):
    """A run directory written by an older version (a format-1 checkpoint, a config.toml
    naming ``env.ped_yield``) is refused in one line naming what wrote it and what to
    do, before any config is read; so is a current one whose config.toml names a field
    this version does not know. A trained agent's directory (``agent.npz``) alike."""
    resolved = load_config("smoke").to_toml()
    old_toml = resolved.replace('ped_behaviour_to_car = "ignore"', "ped_yield = 0")
    assert old_toml != resolved
    old = tmp_path / "old"
    old_writer = {"format": 1, "drqn_jax_version": "0.1.0", "drqn_jax_commit": None}
    _old_run_dir(old, tiny, old_toml, old_writer)
    with pytest.raises(
        CheckpointError,
        match=r"old/checkpoint\.npz: written by drqn_jax 0\.1\.0 in format 1; "
        r"this version reads format 2: train it again, or use the commit that wrote it$",
    ):
        load_run(old)
    edited = tmp_path / "edited"
    _old_run_dir(edited, tiny, old_toml, {"drqn_jax_commit": "abc1234"})
    with pytest.raises(
        CheckpointError,
        match=r"edited/config\.toml, written by drqn_jax \S+ at commit abc1234 in format 2, "
        r"does not load in this version: unknown field env\.ped_yield; \[env\] has: .*; "
        r"train it again, or use the commit that wrote it$",
    ) as refused:
        load_run(edited)
    assert "\n" not in str(refused.value)
    agent = tmp_path / "agent"
    agent.mkdir()
    (agent / "config.toml").write_text(old_toml)
    save_checkpoint(agent, {"w": jnp.zeros(2)}, {}, name=AGENT)
    with pytest.raises(CheckpointError, match=r"agent/config\.toml, written by .* in format 2,"):
        load_run(agent)
    # the run's own config loads; an override's problem stays a ConfigError of its own
    (edited / "config.toml").write_text(resolved)
    assert load_run(edited, ("train.gamma=0.5",))["train"]["gamma"] == 0.5
    with pytest.raises(ConfigError, match=r"^unknown field train\.nope"):
        load_run(edited, ("train.nope=1",))


def test_template_of_another_shape(tmp_path, tiny, template):
    save_checkpoint(tmp_path, tiny[3], {})
    other = make_train(dataclasses.replace(TINY, num_envs=1))
    other_template = jax.eval_shape(other.init, jax.random.key(0))
    with pytest.raises(
        CheckpointError,
        match=r"does not fit the expected state \(\d+ leaves differ\): "
        r"\.env_state\.ego\.s: checkpoint \(2,\) float32, expected \(1,\) float32; .*and \d+ more",
    ):
        load_checkpoint(tmp_path, other_template)

    # another dtype, and a leaf the checkpoint lacks
    changed = template.replace(
        recorded=jax.ShapeDtypeStruct((), jnp.float32),
        metrics={**template.metrics, "extra": jax.ShapeDtypeStruct((3,), jnp.int32)},
    )
    with pytest.raises(
        CheckpointError,
        match=r"\(2 leaves differ\): \.recorded: checkpoint \(\) int32, expected \(\) float32; "
        r"\.metrics\['extra'\]: not in the checkpoint, expected \(3,\) int32$",
    ):
        load_checkpoint(tmp_path, changed)


def test_config_mismatch_names_the_field(tmp_path, tiny, template):
    state5 = tiny[3]
    save_checkpoint(tmp_path, state5, meta_of(state5))
    other = {**CONFIG, "train": {**CONFIG["train"], "batch_size": 16}}
    with pytest.raises(
        CheckpointError,
        match=r"another configuration \(1 field differs\): train\.batch_size: checkpoint 4, "
        r"this run 16$",
    ):
        load_checkpoint(tmp_path, template, {"config": other, "config_hash": config_hash(other)})
    with pytest.raises(CheckpointError, match=r"config_hash [0-9a-f]{12}… in the checkpoint"):
        load_checkpoint(tmp_path, template, {"config_hash": config_hash(other)})
    # the same configuration (tuples are lists once in JSON) loads
    same = {"config": CONFIG, "config_hash": config_hash(CONFIG)}
    load_checkpoint(tmp_path, template, same)


def test_config_hash_is_canonical():
    a = {"b": 1, "a": {"y": [1, 2], "x": "s"}}
    b = {"a": {"x": "s", "y": [1, 2]}, "b": 1}
    assert config_hash(a) == config_hash(b) and len(config_hash(a)) == 64
    assert config_hash(a) != config_hash({**a, "b": 2})


def test_atomic_write_leaves_no_temp_files(tmp_path):
    target = tmp_path / "metrics.csv"
    atomic_write_text(target, "a,b\n1,2\n")
    atomic_write_text(target, "a,b\n3,4\n")
    atomic_write_bytes(tmp_path / "blob.bin", b"\x00\x01")
    assert target.read_text() == "a,b\n3,4\n"
    assert sorted(os.listdir(tmp_path)) == ["blob.bin", "metrics.csv"]
    (tmp_path / "plain").write_text("")  # permissions as open() gives them
    assert target.stat().st_mode & 0o777 == (tmp_path / "plain").stat().st_mode & 0o777
    (tmp_path / "plain").unlink()
    # a failed write removes its temporary file and keeps the old content
    with pytest.raises(TypeError):
        atomic_write_bytes(target, "not bytes")  # type: ignore[arg-type]
    assert sorted(os.listdir(tmp_path)) == ["blob.bin", "metrics.csv"]
    assert target.read_text() == "a,b\n3,4\n"
