"""Run configurations: TOML files in ``configs/`` and ``--set`` overrides, sections ``[run]``
(seed: training key ``split(key(seed))[0]``, evaluation ``[1]``), ``[env]``, ``[network]``,
``[train]``, ``[rule_based]``, ``[planner]``, ``[evaluate]``. :func:`load_config` validates
all before anything compiles; a problem is a one-line :class:`ConfigError`."""

import dataclasses
import hashlib
import json
import math
import re
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax

from drqn_jax.agents.planner import PlannerParams
from drqn_jax.agents.rule_based import RuleBasedParams
from drqn_jax.env.params import KMH, EnvParams, StaticEnvParams
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.learners import Hyperparams, TrainConfig
from drqn_jax.learners.hyperparams import ON_POLICY
from drqn_jax.networks import CELLS, NETWORK_KINDS, NetworkConfig
from drqn_jax.registry import make, preset, registered_envs

#: ``configs/`` of the source tree (the project is installed editable).
CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"

#: The sections a training checkpoint depends on, with ``run.seed``.
TRAINING_SECTIONS = ("env", "network", "train")

#: Fields no result depends on: left out of :meth:`Config.training_dict`.
UNHASHED = {("network", "scan_unroll")}

TRAIN_SIZES = tuple(
    f.name
    for f in dataclasses.fields(TrainConfig)
    if f.name not in ("env_id", "env_overrides", "network", "hyperparams")
)


class ConfigError(ValueError):
    """A configuration problem; the message is one line naming field, value and rule."""


#: Where each section's fields come from, and the fields of those it leaves out.
_SECTIONS = {
    "env": ((StaticEnvParams, EnvParams), ()),
    "network": ((NetworkConfig,), ("grid_shape", "num_actions", "torso", "mlp", "obs_size")),
    "train": ((TrainConfig, Hyperparams), ("env_id",)),
    "rule_based": ((RuleBasedParams,), ()),
    "planner": ((PlannerParams,), ()),
}


def _schema() -> tuple[dict[str, dict[str, Any]], dict[tuple[str, str], tuple[str, ...]]]:
    """Every field's default (a switch's as its name) and each switch's choices."""
    schema: dict[str, dict[str, Any]] = {"run": {"seed": 0, "checkpoint_every_s": 60.0}}
    schema["env"], choices = {"id": "UrbanPedestrians-v0"}, {("env", "id"): registered_envs()}
    for section, (classes, skip) in _SECTIONS.items():
        table = schema.setdefault(section, {})
        for f in (f for cls in classes for f in dataclasses.fields(cls) if f.name not in skip):
            choice = f.metadata.get("choices")
            if choice is not None:  # stored as an index (a traced switch) or as the name
                choices[section, f.name] = choice
                table[f.name] = f.default if isinstance(f.default, str) else choice[f.default]
            elif f.name == "conv":
                table[f.name] = [list(layer) for layer in f.default]
            elif isinstance(f.default, bool | int | float | str):
                table[f.name] = f.default
    choices["network", "kind"], choices["network", "cell"] = NETWORK_KINDS, CELLS
    # episodes per agent (run in batches of evaluation.EVAL_BATCH)
    schema["evaluate"] = {"episodes": 1000}
    return schema, choices


SCHEMA, _CHOICES = _schema()


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_conv(value: Any) -> bool:
    """A non-empty list of ``[kernel_h, kernel_w, stride, filters]`` integer lists."""
    layers = value if isinstance(value, list) and value else [None]
    return all(
        isinstance(v, list) and len(v) == 4 and all(type(x) is int for x in v) for v in layers
    )


#: A field's type (its default's) -> what a value must be, and the test.
_TYPES = {
    bool: ("true or false", lambda v: isinstance(v, bool)),
    int: ("an integer", _is_int),
    float: ("a number", lambda v: _is_int(v) or isinstance(v, float)),
    str: ("a string", lambda v: isinstance(v, str)),
    list: ("a list of [kernel_h, kernel_w, stride, filters] integer lists", _is_conv),
}


def _merge(values: dict[str, dict[str, Any]], section: str, name: str, value: Any) -> None:
    """Check ``section.name = value`` (its type, a switch's choices) and set it in ``values``."""
    if section not in SCHEMA:
        raise ConfigError(
            f"unknown section [{section}] (field {section}.{name}); sections: {', '.join(SCHEMA)}"
        )
    if name not in SCHEMA[section]:
        raise ConfigError(
            f"unknown field {section}.{name}; [{section}] has: {', '.join(SCHEMA[section])}"
        )
    kind = next(k for k in _TYPES if isinstance(SCHEMA[section][name], k))
    (wanted, fits), choices = _TYPES[kind], _CHOICES.get((section, name))
    if not fits(value):
        wanted += f" (one of {', '.join(choices)})" if choices else ""
        raise ConfigError(f"{section}.{name} = {value!r}: must be {wanted}")
    if choices is not None and value not in choices:
        allowed = ", ".join(map(repr, choices))
        raise ConfigError(f"{section}.{name} = {value!r}: must be one of {allowed}")
    if kind is float:
        value = float(value)
    elif kind is list:
        value = [list(layer) for layer in value]
    values[section][name] = value


def parse_override(text: str) -> tuple[str, str, Any]:
    """``"section.field=value"`` -> (section, field, value): a TOML value, else a bare
    string (``--set env.id=UrbanPedestriansRealistic-v0`` needs no quotes)."""
    key, sep, raw = text.partition("=")
    section, dot, name = key.strip().partition(".")
    if not sep or not dot or not section or not name:
        raise ConfigError(f"--set {text!r}: expected section.field=value, e.g. train.gamma=0.95")
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return section, name, value


def config_names() -> tuple[str, ...]:
    """The run presets at the top of ``configs/`` (sweep files, with ``[axes]``, are not)."""
    return tuple(sorted(p.stem for p in CONFIG_DIR.glob("*.toml") if not _is_sweep_file(p)))


def _named_config(name: str) -> Path:
    """``configs/NAME.toml``, else the one ``configs/*/NAME.toml`` (a missing path if none)."""
    top = CONFIG_DIR / f"{name}.toml"
    if top.is_file():
        return top
    found = sorted(p for p in CONFIG_DIR.glob(f"*/{name}.toml") if not _is_sweep_file(p))
    return found[0] if len(found) == 1 else top


def _is_sweep_file(path: Path) -> bool:
    try:
        return "axes" in tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return False  # a broken config: loading it names the error


def _read_toml(source: str | Path) -> tuple[dict[str, Any], str]:
    """A config file's tables and its path; ``source``: a file or a built-in config's name."""
    path = Path(source)
    if not path.suffix and not path.is_file():
        path = _named_config(str(source))
    if not path.is_file():
        names = ", ".join(config_names()) or "(none found)"
        raise ConfigError(f"config {str(source)!r}: no such file; built-in names: {names}")
    try:
        return tomllib.loads(path.read_text()), str(path)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"config {str(path)!r}: not valid TOML: {err}") from None


def _resolve_extends(raw: dict[str, Any], origin: str, depth: int = 0) -> dict[str, Any]:
    """A file's tables on top of those of the config its ``extends`` key names."""
    if "extends" not in raw:
        return raw
    raw = dict(raw)
    parent_name = raw.pop("extends")
    if not isinstance(parent_name, str) or depth > 8:
        raise ConfigError(f"extends = {parent_name!r} in {origin}: must name one config, no cycle")
    parent_source: str | Path = parent_name
    if Path(origin).is_file() and (Path(origin).parent / parent_name).is_file():
        parent_source = Path(origin).parent / parent_name
    parent, parent_origin = _read_toml(parent_source)
    merged = _resolve_extends(parent, parent_origin, depth + 1)
    merged = {k: dict(v) if isinstance(v, dict) else v for k, v in merged.items()}
    for section, table in raw.items():
        if isinstance(table, dict) and isinstance(merged.get(section), dict):
            merged[section].update(table)
        else:
            merged[section] = table
    return merged


def load_config(
    source: str | Path | dict[str, Any] | None = None, overrides: Sequence[str] = ()
) -> "Config":
    """Read ``source`` (a TOML path, a name in ``configs/``, a nested dict, or None for
    the defaults), apply ``section.field=value`` overrides, validate (ConfigError)."""
    if source is None:
        raw, origin = {}, "defaults"
    elif isinstance(source, dict):
        raw, origin = source, "dict"
    else:
        raw, origin = _read_toml(source)
    raw = _resolve_extends(raw, origin)
    given: dict[str, dict[str, Any]] = {section: {} for section in SCHEMA}
    for section, table in raw.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{section} = {table!r}: expected a [{section}] table")
        for name, value in table.items():
            _merge(given, section, name, value)
    file_env_id = given["env"].get("id", SCHEMA["env"]["id"])
    overridden_env: set[str] = set()
    for text in overrides:
        section, name, value = parse_override(text)
        _merge(given, section, name, value)
        if section == "env":
            overridden_env.add(name)

    values = {section: dict(table) for section, table in SCHEMA.items()}
    env_id = given["env"].get("id", values["env"]["id"])
    if env_id != file_env_id:  # the new id brings its preset: drop what repeats the old one's
        old = _env_base(file_env_id)
        for name in [n for n in given["env"] if n != "id" and n not in overridden_env]:
            if given["env"][name] == old[name]:
                del given["env"][name]
    values["env"].update(preset(env_id))
    for section, table in given.items():
        values[section].update(table)
    config = Config(values, origin)
    config.validate()
    return config


def _env_base(env_id: str) -> dict[str, Any]:
    """Every env field of ``env_id``'s preset (the schema's defaults under it)."""
    return {**SCHEMA["env"], **preset(env_id)}


@dataclasses.dataclass(frozen=True, eq=False)
class Config:
    """A resolved configuration: ``values[section][field]`` for every field."""

    values: dict[str, dict[str, Any]]
    origin: str = "dict"

    def __getitem__(self, section: str) -> dict[str, Any]:
        return self.values[section]

    def env_overrides(self) -> dict[str, Any]:
        """``make`` keyword arguments: every env field that differs from the preset."""
        base = _env_base(self["env"]["id"])
        return {n: v for n, v in self["env"].items() if n != "id" and v != base[n]}

    def make_env(self) -> tuple[UrbanPedestrians, EnvParams]:
        return make(self["env"]["id"], **self.env_overrides())

    def speed_limit_kmh(self) -> float:
        """The world's speed limit ``env.v_ref`` in km/h (SPEC §4, §9)."""
        return float(self["env"]["v_ref"]) / KMH

    def network_config(self) -> NetworkConfig:
        net = self["network"]
        return NetworkConfig(**{**net, "conv": tuple(tuple(layer) for layer in net["conv"])})

    def hyperparams(self) -> Hyperparams:
        train = self["train"]
        return Hyperparams(**{n: train[n] for n in SCHEMA["train"] if n not in TRAIN_SIZES})

    def train_config(self) -> TrainConfig:
        train = self["train"]
        return TrainConfig(
            env_id=self["env"]["id"],
            env_overrides=tuple(sorted(self.env_overrides().items())),
            network=self.network_config(),
            hyperparams=self.hyperparams(),
            **{n: train[n] for n in TRAIN_SIZES},
        )

    def rule_based_params(self) -> RuleBasedParams:
        return RuleBasedParams(**self["rule_based"])

    def planner_params(self) -> PlannerParams:
        return PlannerParams(**self["planner"])

    def keys(self) -> tuple[jax.Array, jax.Array]:
        """(training key, evaluation key): the two halves of ``split(key(seed))``."""
        return tuple(jax.random.split(jax.random.key(self["run"]["seed"])))

    def validate(self) -> None:
        """Ranges (through the objects' own checks) and cross-field rules."""
        run, train, evaluate = self["run"], self["train"], self["evaluate"]
        if not 0 <= run["seed"] < 2**32:
            raise ConfigError(f"run.seed = {run['seed']}: must be an integer in [0, 2**32)")
        every = run["checkpoint_every_s"]
        if not (math.isfinite(every) and every > 0):
            raise ConfigError(f"run.checkpoint_every_s = {every}: must be a number > 0")
        if evaluate["episodes"] < 1:
            raise ConfigError(f"evaluate.episodes = {evaluate['episodes']}: must be >= 1")
        try:
            env, _ = self.make_env()
            self.train_config()
            self.rule_based_params()
            self.planner_params()
        except ValueError as err:
            raise ConfigError(_in_config_words(str(err))) from None
        cap, limit = self["planner"]["v_cap"], self["env"]["v_ref"]
        if cap > limit:
            raise ConfigError(f"planner.v_cap = {cap}: must be <= env.v_ref = {limit} (m/s)")
        if train["algorithm"] in ON_POLICY:  # no replay: its sizes are unused
            return
        window, max_steps = train["window"], env.static.max_steps
        if window > max_steps:
            raise ConfigError(f"train.window = {window}: must be <= env.max_steps ({max_steps})")
        batch, replay = train["batch_size"], train["replay_episodes"]
        if batch > replay:
            raise ConfigError(
                f"train.batch_size = {batch}: must be <= train.replay_episodes ({replay})"
            )

    def to_toml(self) -> str:
        """The resolved configuration as TOML (every field; reads back equal)."""
        lines = []
        for section, table in self.values.items():
            lines.append(f"[{section}]")
            lines.extend(f"{name} = {toml_value(value)}" for name, value in table.items())
            lines.append("")
        return "\n".join(lines)

    def training_dict(self) -> dict[str, Any]:
        """What a training run's results depend on: ``run.seed`` and ``TRAINING_SECTIONS``."""
        out: dict[str, Any] = {"run.seed": self["run"]["seed"]}
        for section in TRAINING_SECTIONS:
            out[section] = {
                name: value
                for name, value in self[section].items()
                if (section, name) not in UNHASHED
            }
        return out

    def training_hash(self) -> str:
        """:func:`config_hash` of :meth:`training_dict`."""
        return config_hash(self.training_dict())

    def training_identity(self) -> dict[str, Any]:
        """What a checkpoint stores and loading one checks: the dict and its hash."""
        return {"config": self.training_dict(), "config_hash": self.training_hash()}


def config_hash(config: dict[str, Any]) -> str:
    """SHA-256 hex digest of ``json.dumps(config, sort_keys=True, separators=(",", ":"))``."""
    text = json.dumps(config, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _in_config_words(message: str) -> str:
    """``"Hyperparams.gamma = 2: ..."`` -> ``"train.gamma = 2: ..."``."""
    for section, (classes, _) in _SECTIONS.items():
        names = "|".join(cls.__name__ for cls in classes)
        message = re.sub(rf"\b(?:{names})\.", f"{section}.", message)
        message = re.sub(rf"^(?:{names}):", f"[{section}]:", message)
    return message


def toml_value(value: Any) -> str:
    """A bool, int, float, string or list of them as TOML (what JSON writes, floats by
    ``repr``, which reads back to the same float)."""
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, bool | int | str):
        return json.dumps(value)
    raise TypeError(f"cannot write {value!r} as TOML")
