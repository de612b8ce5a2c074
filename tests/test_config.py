"""Configs: the shipped TOML files, --set overrides, validation before compiling, round trips."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest

from drqn_jax.config import (
    CONFIG_DIR,
    SCHEMA,
    UNHASHED,
    ConfigError,
    config_names,
    load_config,
    parse_override,
)
from drqn_jax.learners import TrainConfig
from drqn_jax.networks import NetworkConfig


def changed(preset, base, section: str) -> dict:
    """The fields of ``section`` whose value in ``preset`` differs from ``base``'s."""
    return {k: v for k, v in preset[section].items() if v != base[section][k]}


def _shipped(folder: str = "*") -> list[Path]:
    """Every config file under configs/ (sweep files included), top level and folders."""
    return sorted(CONFIG_DIR.glob("*.toml")) + sorted(CONFIG_DIR.glob(f"{folder}/*.toml"))


def test_presets_say_when_they_have_a_teacher():
    """Teacher-free by default: a shipped config learns from the reward alone unless
    its name says ``teacher`` (and then it has one: guided exploration or imitation);
    a sweep whose name does not say so has no teacher at any point."""
    from drqn_jax.config import _is_sweep_file
    from drqn_jax.experiments.sweep import load_sweep
    from drqn_jax.learners.hyperparams import REWARD_ALONE, teacher_label

    for path in _shipped():
        if _is_sweep_file(path):
            if "teacher" not in path.stem:
                for point in load_sweep(path).points:
                    assert teacher_label(point.config.hyperparams()) == REWARD_ALONE, path
            continue
        label = teacher_label(load_config(path.stem).hyperparams())
        assert (label != REWARD_ALONE) == ("teacher" in path.stem), (path, label)


def test_configs_are_laid_out_by_purpose():
    """Issue 42: at most 8 run presets at the top of configs/, sweeps only in sweeps/,
    every config within 2 levels of ``extends``, and every name unique (names load from
    the folders too)."""
    from drqn_jax.config import _is_sweep_file, _read_toml

    top = sorted(CONFIG_DIR.glob("*.toml"))
    assert len(top) <= 8 and not any(_is_sweep_file(p) for p in top), top
    assert set(config_names()) == {p.stem for p in top}
    assert {"paper", "default", "realistic", "smoke"} <= set(config_names())
    assert all(_is_sweep_file(p) for p in CONFIG_DIR.glob("sweeps/*.toml"))
    stems = [p.stem for p in _shipped()]
    assert len(stems) == len(set(stems)), "two configs share a name"
    for path in _shipped():
        raw, levels = tomllib.loads(path.read_text()), 0
        while "extends" in raw:
            raw, levels = _read_toml(raw["extends"])[0], levels + 1
        assert levels <= 2, (path, levels)


def test_shipped_configs_load_and_run_directories_do_not_need_them(tmp_path):
    """Every shipped config builds; the config.toml a run writes is self-contained
    (no ``extends``), so a run of a preset since moved or changed still loads alike."""
    from drqn_jax.config import _is_sweep_file

    for path in _shipped():
        if _is_sweep_file(path):
            continue
        config = load_config(path.stem)
        config.train_config()  # builds every object
        written = tmp_path / f"{path.stem}.toml"
        written.write_text(config.to_toml())
        assert "extends" not in tomllib.loads(written.read_text())
        assert load_config(written).training_hash() == config.training_hash(), path


def test_shipped_sweep_files_validate():
    """Every sweep file in configs/sweeps/ names valid points."""
    from drqn_jax.experiments.sweep import load_sweep

    sweeps = sorted(CONFIG_DIR.glob("sweeps/*.toml"))
    assert {p.stem for p in sweeps} == {"sweep", "occlusion"}
    for path in sweeps:
        assert load_sweep(path).points


def test_paper_config_is_the_papers_protocol():
    """paper.toml is SPEC §7's protocol: TrainConfig's defaults, which cite Table II."""
    config = load_config("paper")
    got = config.train_config()
    want = TrainConfig(chunk_iterations=got.chunk_iterations)
    assert got == want
    assert got.network == NetworkConfig()
    assert config["env"]["max_steps"] == 1000 and config.env_overrides() == {}


def test_dqn_stack_is_default_with_a_frame_stacking_dqn():
    default, stack = load_config("default"), load_config("dqn-stack")
    assert changed(stack, default, "network") == {"kind": "dqn", "frames": 4}
    assert stack["train"] == default["train"] and stack["env"] == default["env"]
    assert stack.network_config().frames == 4
    assert stack.training_dict()["network"]["frames"] == 4
    assert default.training_dict()["network"]["frames"] == 1


def test_realistic_extends_default_with_walking_speeds():
    default, realistic = load_config("default"), load_config("realistic")
    assert realistic["env"]["id"] == "UrbanPedestriansRealistic-v0"
    assert realistic["env"]["ped_speed_max"] == 1.5 and default["env"]["ped_speed_max"] < 0.5
    assert realistic["train"] == default["train"] and realistic["network"] == default["network"]
    assert realistic["env"]["reward_collision"] == default["env"]["reward_collision"] == -100.0


def test_set_overrides_and_parsing():
    config = load_config(
        "smoke",
        [
            "train.learning_rate=3e-4",
            "env.id=UrbanPedestriansRealistic-v0",  # a bare string
            'train.clip="grad"',
            "network.conv=[[8, 6, 4, 4], [4, 3, 3, 4], [2, 2, 2, 4]]",
            "train.gamma=1",  # an int for a float field
        ],
    )
    assert config["train"]["learning_rate"] == 3e-4
    assert config["env"]["id"] == "UrbanPedestriansRealistic-v0"
    assert config["train"]["clip"] == "grad" and config["train"]["gamma"] == 1.0
    assert config.network_config().conv[2] == (2, 2, 2, 4)
    assert parse_override("run.seed = 7") == ("run", "seed", 7)
    with pytest.raises(ConfigError, match=r"section\.field=value"):
        parse_override("learning_rate=1")


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("train.learning_rate=-3e-4", r"train\.learning_rate = -0\.0003: out of range"),
        ("train.window=31", r"train\.window = 31: must be <= env\.max_steps \(30\)"),
        ("train.window_start=end", r"train\.window_start = 'end': must be one of 'inside'"),
        ("train.n_step=0", r"train\.n_step = 0: must be an integer >= 1"),
        ("train.n_step=5", r"train\.n_step = 5: must be <= window \(4\)"),
        ("train.batch_size=5", r"train\.batch_size = 5: must be <= train\.replay_episodes \(4\)"),
        ("train.learning_starts=3", r"train\.learning_starts = 3: must be <= 2"),
        ("train.num_envs=2.5", r"train\.num_envs = 2\.5: must be an integer"),
        ("train.gamma=true", r"train\.gamma = True: must be a number"),
        ("network.layer_norm=1", r"network\.layer_norm = 1: must be true or false"),
        ("train.optimizer=sgd", r"train\.optimizer = 'sgd': must be one of 'adam', 'radam'"),
        ("train.clip=none", r"train\.clip = 'none': must be one of 'huber', 'grad'"),
        ("train.lr=1", r"unknown field train\.lr; \[train\] has: .*learning_rate"),
        ("trian.gamma=1", r"unknown section \[trian\]"),
        ("env.id=Nope-v0", r"env\.id = 'Nope-v0': must be one of"),
        ("env.max_steps=0", r"env\.max_steps = 0: must be an integer >= 1"),
        ("env.prob_crossing=0.9", r"\[env\]|prob_crossing"),
        ("network.kind=lstm", r"network\.kind = 'lstm': must be one of"),
        ("network.scan_unroll=0", r"network\.scan_unroll = 0: must be an integer >= 1"),
        ("network.conv=[[8, 6, 4]]", r"network\.conv = .*kernel_h, kernel_w, stride, filters"),
        ("network.conv=[[50, 6, 4, 8]]", r"network\.conv = .*shrinks to nothing"),
        ("run.seed=-1", r"run\.seed = -1"),
        ("run.checkpoint_every_s=0", r"run\.checkpoint_every_s = 0\.0: must be a number > 0"),
        ("evaluate.episodes=0", r"evaluate\.episodes = 0: must be >= 1"),
        ("train.explore_brake=0.3", r"explore_brake \(0\.3\).*must sum to 1"),
        ("env.ped_speed_min=2", r"env\.ped_speed_min = 2 and env\.ped_speed_max"),
        ("train.algorithm=sac", r"train\.algorithm = 'sac': must be one of 'dqn', 'ppo'"),
        ("train.num_env_steps=-1", r"train\.num_env_steps = -1: must be an integer >= 0"),
        ("train.algorithm=ppo", r"train\.num_minibatches = 4: must divide num_envs \(2\)"),
    ],
)
def test_bad_values_name_field_value_and_rule(override, message):
    with pytest.raises(ConfigError, match=message) as info:
        load_config("smoke", [override])
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("train.explore_guide=0.5", r"train\.explore_guide = 0\.5: algorithm 'ppo' learns"),
        ("train.stored_state=1", r"train\.stored_state = 1: algorithm 'ppo' has no replay"),
        ("train.snapshots=1", r"train\.snapshots = 1: algorithm 'ppo' has no replay"),
    ],
)
def test_ppo_refuses_what_it_cannot_do(override, message):
    with pytest.raises(ConfigError, match=message):  # (no step budget: snapshots need none)
        load_config("ppo", ["train.num_env_steps=0", override])
    assert load_config("ppo").train_config().algorithm == "ppo"


def test_a_directory_named_like_a_preset_does_not_hide_it(tmp_path, monkeypatch):
    """A run directory called ``default`` in the working directory (``drqn-jax
    reproduce --run-dir default``) is no config: the preset, and the presets
    that extend it, still load."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "default").mkdir()
    assert load_config("default").values == load_config(CONFIG_DIR / "default.toml").values
    assert load_config("dqn")["network"]["kind"] == "dqn"


def test_unknown_fields_in_files_and_bad_toml(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[train]\nbatchsize = 4\n")
    with pytest.raises(ConfigError, match=r"unknown field train\.batchsize"):
        load_config(bad)
    bad.write_text("[train\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)
    with pytest.raises(ConfigError, match=r"no such file; built-in names: .*paper"):
        load_config("no-such-config")


def test_resolved_toml_reads_back_equal(tmp_path):
    config = load_config("realistic", ["train.learning_rate=3e-4", "env.max_steps=300"])
    path = tmp_path / "resolved.toml"
    path.write_text(config.to_toml())
    again = load_config(path)
    assert again.values == config.values
    assert again.training_hash() == config.training_hash()
    assert again.train_config() == config.train_config()
    # every field of every section is written out
    assert {s: set(t) for s, t in again.values.items()} == {s: set(t) for s, t in SCHEMA.items()}


def test_an_env_id_override_brings_its_preset_into_a_resolved_config(tmp_path):
    """A run's config.toml holds every env field, its id's preset included; ``--set
    env.id=...`` must evaluate among the new id's pedestrians, not the old speeds."""
    path = tmp_path / "config.toml"
    path.write_text(load_config("realistic", ["env.occlusion_prob=0.2"]).to_toml())
    moved = load_config(path, ["env.id=UrbanPedestrians-v0"])
    paper = load_config("default", ["env.occlusion_prob=0.2"])
    assert moved["env"] == paper["env"]  # the paper's speeds; the changed field kept
    assert moved["env"]["ped_speed_max"] != load_config(path)["env"]["ped_speed_max"]
    both = load_config(path, ["env.id=UrbanPedestrians-v0", "env.ped_speed_max=1.5"])
    assert both["env"]["ped_speed_max"] == 1.5  # a field overridden too stays as given


def test_training_hash_tracks_training_fields_only():
    base = load_config("smoke")
    assert load_config("smoke", ["evaluate.episodes=3"]).training_hash() == base.training_hash()
    assert (
        load_config("smoke", ["run.checkpoint_every_s=9"]).training_hash() == base.training_hash()
    )
    for override in (
        "train.gamma=0.5",
        "env.max_steps=31",
        "network.hidden=8",
        "run.seed=1",
        "train.n_step=3",
        "train.window_start=anywhere",
    ):
        assert load_config("smoke", [override]).training_hash() != base.training_hash(), override


def test_the_training_hash_is_of_every_training_field_but_the_unhashed():
    """``run.seed`` and every ``[env]``, ``[network]`` and ``[train]`` field, at any
    value, under its own name; ``network.scan_unroll`` changes no bit, so a run resumes
    with another."""
    config = load_config("smoke")
    hashed = config.training_dict()
    assert set(hashed) == {"run.seed", "env", "network", "train"}
    assert hashed["run.seed"] == config["run"]["seed"]
    for section in ("env", "network", "train"):
        kept = {n: v for n, v in config[section].items() if (section, n) not in UNHASHED}
        assert hashed[section] == kept, section
    assert {("network", "scan_unroll")} == UNHASHED
    assert "scan_unroll" not in hashed["network"]
    unrolled = load_config("smoke", ["network.scan_unroll=9"])
    assert unrolled.network_config().scan_unroll == 9
    assert unrolled.training_hash() == config.training_hash()
    for default in ("env.collision_model=authors", "train.n_step=1", "network.cell=lstm"):
        assert load_config("smoke", [default]).training_hash() == config.training_hash()
    for override in ("env.collision_model=contact", "train.q_lambda=0.5", "network.cell=gru"):
        assert load_config("smoke", [override]).training_hash() != config.training_hash()


def test_a_field_this_version_does_not_know_is_refused():
    """No old names are read: a config naming a field of no section (a run directory of
    another version) is refused in one line naming it."""
    values = {**load_config("smoke").values}
    values["env"] = {**values["env"], "ped_yield": 1}
    with pytest.raises(ConfigError, match=r"^unknown field env\.ped_yield; \[env\] has: id, "):
        load_config(values)
    with pytest.raises(ConfigError, match=r"^unknown field env\.ped_yield;"):
        load_config("smoke", ["env.ped_yield=1"])


def test_env_overrides_are_the_difference_from_the_preset():
    config = load_config("realistic", ["env.max_steps=300"])
    recipe = {"reward_collision": -100.0, "reward_stopped": -0.1, "reward_overspeed": -2.0}
    assert config.env_overrides() == {"max_steps": 300, **recipe}
    env, params = config.make_env()
    assert env.static.max_steps == 300 and float(params.ped_speed_max) == 1.5
    assert float(params.reward_collision) == -100.0
    assert dataclasses.asdict(env.static)["num_pedestrians"] == 10
