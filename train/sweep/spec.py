"""The sweep file: what varies across a sweep's trials, and how they run (TOML, checked on load).

A sweep is a base training config (a preset and ``--set`` overrides, exactly as ``colorgrid
train`` takes them), parameters that vary over training-config keys, and seeds. Every grid
combination, times ``num_samples`` draws of the random parameters, times every seed is one
trial. ``load_sweep`` raises ``SweepError`` with the place in the file and what is allowed
(``params.aux.grid[1]: follower.aux_coef=-1 is invalid: a number >= 0``). See docs/SWEEPS.md.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from colorgrid.configkit import ConfigError, merge
from train.sweep.checks import SUMMARY_SUFFIXES, SweepError, bad, same_value
from train.sweep.claim_spec import parse_claims
from train.config import TrainConfig, eval_stream, from_dict, load_preset, parse_override

GRID_KINDS = ("grid", "options")
RANDOM_KINDS = ("choice", "uniform", "loguniform")
KINDS = GRID_KINDS + RANDOM_KINDS
MODES = ("max", "min")
SCHEDULERS = ("none", "asha")
NAME_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
TOP_LEVEL = ("description", "preset", "set", "seeds", "params", "num_samples", "metric", "mode", "final_window",
             "out", "resources", "scheduler", "paper", "claim", "results")
MAX_COMBINATIONS = 10_000
RESERVED = ("seed", "sample", "trial", "configuration", "step", "steps", "total_steps", "finished", "node")
"""Names a parameter may not take: Tune's axes and the columns of the sweep's tables."""
SPEC_FILE = "sweep.toml"
"""The sweep file as read, kept in the sweep's folder (``sweep resume`` and ``sweep report`` read it)."""
WORKDIR_FILE = "workdir"
"""The folder the sweep was started in: paths in the sweep file are read from there, on resume too."""


@dataclass(frozen=True)
class Param:
    """One parameter that varies: over listed values (``grid``), named bundles of settings (``options``), or
    random draws (``choice``, ``uniform``, ``loguniform``); its value sets every key of ``keys``."""

    name: str
    """Its column in the sweep's tables."""
    kind: str
    values: tuple = ()
    """``grid``/``choice``: the values; ``uniform``/``loguniform``: ``(low, high)``; ``options``: the labels."""
    keys: tuple[str, ...] = ()
    """Training-config keys (``ppo.lr``, ``follower.aux_coef``) the value sets; empty for ``options``."""
    options: dict[str, dict] = field(default_factory=dict)
    """``options``: each label's settings, ``{training key: value}``."""

    @property
    def random(self) -> bool:
        return self.kind in RANDOM_KINDS

    def overrides(self, value) -> list[str]:
        """The ``--set`` lines that this parameter's ``value`` (a label, for options) stands for."""
        if self.kind == "options":
            return [f"{key}={to_json(v)}" for key, v in self.options[value].items()]
        return [f"{key}={to_json(value)}" for key in self.keys]

    def corners(self) -> tuple:
        """The values a check on load builds configs from: every listed value, or both ends of a range."""
        return self.values


@dataclass(frozen=True)
class Resources:
    cpus_per_trial: float = 1
    """CPU cores each trial gets; its torch and numba threads are limited to it (rounded up, at least 1)."""
    gpus_per_trial: float = 0
    """GPUs each trial gets (fractions share one); with any, the trials train on ``cuda``."""
    max_concurrent: int = 0
    """Trials at once (0: as many as the cluster's CPUs fit)."""


@dataclass(frozen=True)
class Scheduler:
    kind: str = "none"
    """``none`` (every trial runs to the end) or ``asha`` (stops trials whose metric trails, at rungs)."""
    grace_period: int = 0
    """``asha``: env steps before a trial may be stopped (0: a tenth of ``total_steps``)."""
    reduction_factor: float = 3
    """``asha``: at each rung, the best 1/reduction_factor of trials go on."""


@dataclass(frozen=True)
class PaperFigure:
    """A number the paper reports for one configuration, shown beside the sweep's own in its report."""

    where: dict
    """The configuration: ``{parameter name: value or option label}``."""
    value: float
    note: str = ""


@dataclass(frozen=True)
class SweepSpec:
    """A sweep file, checked: see the module docstring and docs/SWEEPS.md."""

    name: str
    path: Path
    base: dict
    """The base training config as plain data (preset merged with ``set``), seed excluded."""
    seeds: tuple[int, ...]
    params: tuple[Param, ...]
    metric: str
    mode: str = "max"
    final_window: int = 10
    """The final value of a metric is its mean over the trial's last this many reports."""
    num_samples: int = 1
    out: Path = Path("runs/sweeps")
    resources: Resources = field(default_factory=Resources)
    scheduler: Scheduler = field(default_factory=Scheduler)
    paper: tuple[PaperFigure, ...] = ()
    claims: tuple = ()
    """The paper's claims to decide (``train.sweep.claims.Claim``), each with its verdict in the report."""
    results: Path | None = None
    """A folder of finished trials' results kept with the project (``sweep publish`` writes it): ``sweep run``
    skips the trials whose results it holds, and ``sweep report`` reads them with the sweep's own."""
    description: str = ""
    text: str = ""
    """The file as read (kept in the sweep's folder, so that ``sweep resume`` rebuilds the same trials)."""

    @property
    def param_names(self) -> list[str]:
        return [p.name for p in self.params]

    def values(self, params: dict) -> dict:
        """A trial's parameter values by name (listed values, option labels, random draws) from Tune's params."""
        values = {p.name: params.get(p.name) for p in self.params if not p.random}
        values.update(params.get("sample") or {})
        return values

    def label(self, values: dict) -> str:
        """A configuration's name in tables and pictures: ``aux=0.2, annealing=none`` (random draws to 4 digits)."""
        parts = [f"{p.name}={values.get(p.name):.4g}" if p.random and isinstance(values.get(p.name), float)
                 else f"{p.name}={values.get(p.name)}" for p in self.params]
        return ", ".join(parts) or "base"

    def config(self, values: dict, seed: int) -> TrainConfig:
        """The training config of the trial with parameter ``values`` (by name) and ``seed``."""
        data = self.base
        for param in self.params:
            for line in param.overrides(values[param.name]):
                data = merge(data, parse_override(line))
        return from_dict({**data, "seed": seed})

    def missing_files(self) -> list[str]:
        """``SETTING=PATH`` for each checkpoint file a trial names (a learner's ``init``, a frozen partner's file) that
        does not exist, read from the current folder as a trial reads it, over every configuration of the sweep."""
        from colorgrid.policies.registry import file_of

        fixed = [p for p in self.params if not p.random]
        configs = [self.config({**dict(zip((p.name for p in fixed), combo)), **sample}, self.seeds[0])
                   for combo in itertools.product(*(p.values for p in fixed)) for sample in self.samples()]
        missing = {}
        for config in configs:
            for role, agent in zip(config.env.roles, config.agents):
                named = ((f"{role}.init", agent.init), (f"{role}.policy", file_of(agent.policy)))
                missing.update({f"{key}={path}": None for key, path in named if path and not Path(path).exists()})
        return list(missing)

    def check_files(self) -> None:
        """Refuse, in one line, a sweep whose trials name checkpoint files that do not exist (``missing_files``):
        every trial would fail at its start."""
        missing = self.missing_files()
        if missing:
            raise SweepError(f"{self.path}: the trials name checkpoint files that do not exist (read from "
                             f"{Path.cwd()}): {', '.join(missing)}; make them first (the file's description may "
                             f"say how) or name others")

    def grid_size(self) -> int:
        return math.prod(len(p.values) for p in self.params if not p.random)

    def num_trials(self) -> int:
        return self.grid_size() * self.num_samples * len(self.seeds)

    def summary(self) -> str:
        return (f"{self.num_trials()} trials ({self.grid_size() * self.num_samples} configurations x "
                f"{len(self.seeds)} seeds)")

    def samples(self) -> list[dict]:
        """``num_samples`` draws of the random parameters (``{name: value}`` each; one empty draw if none), made
        once from a generator seeded by the sweep file's text, so that every seed of a configuration shares its
        draw and the file kept in the sweep's folder draws the same again."""
        import zlib

        import numpy as np

        rng = np.random.default_rng(zlib.crc32(self.text.encode()))
        draws = []
        for _ in range(self.num_samples):
            draw = {}
            for p in self.params:
                if p.kind == "choice":
                    draw[p.name] = p.values[int(rng.integers(len(p.values)))]
                elif p.kind == "uniform":
                    draw[p.name] = float(rng.uniform(*p.values))
                elif p.kind == "loguniform":
                    draw[p.name] = float(np.exp(rng.uniform(np.log(p.values[0]), np.log(p.values[1]))))
            draws.append(draw)
        return draws


def load_folder(folder: str | Path) -> SweepSpec:
    """The sweep in ``folder`` (made by ``sweep run``), from the file kept there; named after the folder."""
    folder = Path(folder)
    if not (folder / SPEC_FILE).is_file():
        raise SweepError(f"{folder}: not a sweep folder (no {SPEC_FILE}); colorgrid sweep run FILE makes one")
    return dataclasses.replace(load_sweep(folder / SPEC_FILE, out=folder), name=folder.name)


def to_json(value) -> str:
    import json

    return json.dumps(value)


def load_sweep(path: str | Path, out: str | Path | None = None) -> SweepSpec:
    """Read and check a sweep file (a path, or the name of a shipped one: ``paper_table1_small``); ``out``
    replaces the file's ``out``."""
    from colorgrid.resources import find_shipped

    path = find_shipped(path, "sweeps", ".toml")
    if not path.is_file():
        raise SweepError(f"{path}: no such sweep file")
    text = path.read_text()
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SweepError(f"{path}: not valid TOML: {err}") from None
    try:
        return parse_sweep(data, path, text, out)
    except SweepError as err:
        raise SweepError(f"{path}: {err}") from None


def parse_sweep(data: dict, path: Path, text: str = "", out: str | Path | None = None) -> SweepSpec:
    unknown = sorted(set(data) - set(TOP_LEVEL))
    if unknown:
        raise SweepError(f"unknown field {unknown[0]!r}; allowed: {list(TOP_LEVEL)}")
    base = base_config(data)
    seeds = data.get("seeds", [0])
    if (not isinstance(seeds, list) or not seeds or not all(_is_int(s) and s >= 0 for s in seeds)
            or len(set(seeds)) != len(seeds)):
        raise bad("seeds", seeds, "a list of distinct whole numbers >= 0, e.g. [0, 1, 2]")
    params = tuple(parse_param(name, value) for name, value in _table(data, "params").items())
    owners: dict[str, str] = {}
    for param in params:
        for key in {*param.keys, *(k for o in param.options.values() for k in o)}:
            if key in owners:
                raise bad(f"params.{param.name}", key, f"a key no other parameter sets (params.{owners[key]} "
                                                       f"sets it too)")
            owners[key] = param.name
    num_samples = data.get("num_samples", 1)
    if not _is_int(num_samples) or num_samples < 1:
        raise bad("num_samples", num_samples, "a whole number >= 1 (draws of the random parameters per grid point)")
    if num_samples > 1 and not any(p.random for p in params):
        raise bad("num_samples", num_samples, "1 unless a parameter is random (choice, uniform, loguniform)")
    mode = data.get("mode", "max")
    if mode not in MODES:
        raise bad("mode", mode, "'max' or 'min'")
    final_window = data.get("final_window", 10)
    if not _is_int(final_window) or final_window < 1:
        raise bad("final_window", final_window, "a whole number >= 1 (reports averaged for a final value)")
    spec = SweepSpec(
        name=path.stem, path=path, base=base, seeds=tuple(seeds), params=params,
        metric=data.get("metric", "team_reward"), mode=mode, final_window=final_window, num_samples=num_samples,
        out=Path(out) if out is not None else Path(_string(data, "out", f"runs/sweeps/{path.stem}")),
        resources=parse_resources(_table(data, "resources")), scheduler=parse_scheduler(_table(data, "scheduler")),
        paper=(), description=_string(data, "description", ""), text=text)
    results = data.get("results")
    if results is not None and (not isinstance(results, str) or not results.strip()):
        raise bad("results", results, "a folder for the finished trials' results, e.g. 'docs/reproduction/x'")
    check_configs(spec)
    check_metric(spec)
    spec = _with_paper(spec, data.get("paper", []))
    return dataclasses.replace(spec, claims=parse_claims(spec.params, spec.metric, summarised_columns(spec),
                                                         data.get("claim", [])),
                               results=Path(results) if results else None)


def base_config(data: dict) -> dict:
    preset = _string(data, "preset", "default")
    try:
        base = load_preset(preset)
    except ConfigError as err:
        raise SweepError(f"preset: {err}") from None
    lines = data.get("set", [])
    if not isinstance(lines, list) or not all(isinstance(s, str) for s in lines):
        raise bad("set", lines, "a list of KEY=VALUE strings, as colorgrid train --set takes them")
    for i, line in enumerate(lines):
        try:
            override = parse_override(line)
        except ConfigError as err:
            raise SweepError(f"set[{i}]: {err}") from None
        if "seed" in override:
            raise bad(f"set[{i}]", line, "any training key but seed (the sweep's seeds set it)")
        base = merge(base, override)
    try:
        from_dict(base)
    except ConfigError as err:
        raise SweepError(f"preset {preset!r} with set: {err}") from None
    return {k: v for k, v in base.items() if k != "description"}


def parse_param(name: str, value) -> Param:
    where = f"params.{name}"
    if not NAME_PATTERN.match(name) or name in RESERVED:
        raise bad("params", name, f"names of 1 to 64 letters, digits, '_', '.' or '-', other than {list(RESERVED)}")
    if isinstance(value, list):  # the short form: a training key and its values
        value = {"grid": value}
    if not isinstance(value, dict):
        raise bad(where, value, f"a list of values, or a table with one of {list(KINDS)}")
    kinds = [k for k in KINDS if k in value]
    unknown = sorted(set(value) - set(KINDS) - {"keys"})
    if unknown:
        raise SweepError(f"{where}: unknown field {unknown[0]!r}; allowed: 'keys' and one of {list(KINDS)}")
    if len(kinds) != 1:
        raise SweepError(f"{where}: needs exactly one of {list(KINDS)}, found {kinds or 'none'}")
    kind = kinds[0]
    raw = value[kind]
    if kind == "options":
        if "keys" in value:
            raise SweepError(f"{where}: 'keys' is for listed or random values; each option names its own keys")
        if not isinstance(raw, dict) or not raw:
            raise bad(f"{where}.options", raw, "a table of labels, each a table of {training key = value}")
        for label, settings in raw.items():
            if not isinstance(settings, dict):
                raise bad(f"{where}.options.{label}", settings, "a table of {training key = value} ({} for none)")
            for key in settings:
                _check_key(f"{where}.options.{label}", key)
        return Param(name, kind, tuple(raw), (), {label: dict(s) for label, s in raw.items()})
    keys = value.get("keys", [name])
    if not isinstance(keys, list) or not keys or not all(isinstance(k, str) for k in keys):
        raise bad(f"{where}.keys", keys, "a list of training keys, e.g. ['leader.aux_coef', 'follower.aux_coef']")
    for key in keys:
        _check_key(f"{where}.keys" if "keys" in value else where, key)
    if kind in ("grid", "choice"):
        if not isinstance(raw, list) or not raw:
            raise bad(f"{where}.{kind}", raw, "a non-empty list of values")
        if len({to_json(v) for v in raw}) != len(raw):
            raise bad(f"{where}.{kind}", raw, "distinct values")
        return Param(name, kind, tuple(raw), tuple(keys))
    if (not isinstance(raw, list) or len(raw) != 2 or not all(_is_number(v) for v in raw) or not raw[0] < raw[1]
            or (kind == "loguniform" and raw[0] <= 0)):
        low = "0 < low < high" if kind == "loguniform" else "low < high"
        raise bad(f"{where}.{kind}", raw, f"[low, high] with {low}")
    return Param(name, kind, (float(raw[0]), float(raw[1])), tuple(keys))


def _check_key(where: str, key: str) -> None:
    if key == "seed":
        raise bad(where, key, "any training key but seed (list seeds in 'seeds')")
    probe = f"{key}=0"
    try:
        parse_override(probe)
    except ConfigError as err:
        raise SweepError(f"{where}: {str(err).replace(f' in {probe!r}', '')}") from None


def parse_resources(data: dict) -> Resources:
    _no_unknown("resources", data, ("cpus_per_trial", "gpus_per_trial", "max_concurrent"))
    cpus, gpus, concurrent = (data.get("cpus_per_trial", 1), data.get("gpus_per_trial", 0),
                              data.get("max_concurrent", 0))
    if not _is_number(cpus) or cpus <= 0:
        raise bad("resources.cpus_per_trial", cpus, "a number > 0")
    if not _is_number(gpus) or gpus < 0:
        raise bad("resources.gpus_per_trial", gpus, "a number >= 0")
    if not _is_int(concurrent) or concurrent < 0:
        raise bad("resources.max_concurrent", concurrent, "a whole number >= 0 (0: as many as fit)")
    return Resources(cpus, gpus, concurrent)


def parse_scheduler(data: dict) -> Scheduler:
    _no_unknown("scheduler", data, ("kind", "grace_period", "reduction_factor"))
    kind = data.get("kind", "none")
    if kind not in SCHEDULERS:
        raise bad("scheduler.kind", kind, f"one of {list(SCHEDULERS)}")
    grace, factor = data.get("grace_period", 0), data.get("reduction_factor", 3)
    if not _is_int(grace) or grace < 0:
        raise bad("scheduler.grace_period", grace, "a whole number of env steps >= 0 (0: a tenth of total_steps)")
    if not _is_number(factor) or factor <= 1:
        raise bad("scheduler.reduction_factor", factor, "a number > 1")
    if kind == "none" and len(data) > 1:
        raise SweepError("scheduler: grace_period and reduction_factor need kind = 'asha'")
    return Scheduler(kind, grace, factor)


def check_configs(spec: SweepSpec) -> None:
    """Build the training config of every grid combination (random parameters at both ends of their range; the
    first ``MAX_COMBINATIONS``), so that a bad value fails now, in one line, and not in a trial an hour later."""
    corners = [[(p.name, v) for v in p.corners()] for p in spec.params]
    totals = set()
    for i, combination in enumerate(itertools.product(*corners)):
        if i >= MAX_COMBINATIONS:
            break
        values = dict(combination)
        try:
            config = spec.config(values, spec.seeds[0])
        except ConfigError as err:
            where = ", ".join(f"{k}={v!r}" for k, v in values.items())
            raise SweepError(f"params ({where}): {err}") from None
        totals.add(config.num_iterations * config.batch_steps)
    if spec.scheduler.kind == "asha":
        if len(totals) > 1:
            raise bad("scheduler.kind", "asha", f"a sweep whose trials all train as long (total_steps varies: "
                                                f"{sorted(totals)}), or kind = 'none'")
        if spec.scheduler.grace_period >= min(totals):
            raise bad("scheduler.grace_period", spec.scheduler.grace_period,
                      f"fewer env steps than total_steps={min(totals)}")


def summarised_columns(spec: SweepSpec) -> set[str]:
    """The training-log columns whose finals the trials table holds besides the metric (claims may compare them)."""
    fixed = {p.name: p.values[0] for p in spec.params if not p.random}
    columns = metric_columns(spec.config({**fixed, **spec.samples()[0]}, spec.seeds[0]))
    return {c for c in columns if c.endswith(SUMMARY_SUFFIXES)}


def metric_columns(config: TrainConfig) -> set[str]:
    """The columns of the training log a sweep can take as its metric (learner statistics, ``NAME/key``, aside)."""
    from train.metrics import episode_columns

    import numpy as np

    A = config.env.num_agents
    totals = {k: np.zeros((1, A)) for k in ("block_reward", "goal_pickups", "wrong_pickups", "net_pickups",
                                                  "training_reward")}
    columns = {"team_reward", "penalty_coef", "sps", "episodes", *episode_columns(config.env, totals)}
    names = [*config.env.agent_names, *([f"{r}s" for r in ("leader", "follower")] if not config.env.one_to_one
                                        else [])]
    evaluation = {"team_reward", *(f"{n}_{k}" for n in names for k in ("goal_pickups", "wrong_pickups",
                                                                       "net_pickups", "goal_accuracy"))}
    streams = ["eval", *(eval_stream(p) for p in config.eval_partners)]
    return columns | {f"{s}/{c}" for s in streams for c in evaluation}


def check_metric(spec: SweepSpec) -> None:
    if not isinstance(spec.metric, str) or not spec.metric:
        raise bad("metric", spec.metric, "a column of the training log, e.g. 'team_reward'")
    config = spec.config({p.name: p.values[0] for p in spec.params}, spec.seeds[0])
    evaluations = ("eval", *(eval_stream(p) for p in config.eval_partners))
    if "/" in spec.metric and spec.metric.split("/")[0] not in evaluations:  # a learner's statistic (follower/aux_loss)
        learners = [name for name, _ in config.networks] + list(config.env.agent_names)
        if spec.metric.split("/")[0] not in learners:
            raise bad("metric", spec.metric, f"a column of the training log, or a learner's statistic: "
                                             f"'NAME/key' with NAME one of {learners}")
        return
    columns = metric_columns(config)
    if spec.metric not in columns:
        raise bad("metric", spec.metric, f"a column of the training log: one of {sorted(columns)}, or a learner's "
                                         f"statistic such as 'follower/aux_loss'")
    if spec.metric.split("/")[0] in evaluations and not config.eval_every:
        raise bad("metric", spec.metric, "a training column, or set eval_every > 0 for an evaluation column")


def _with_paper(spec: SweepSpec, rows) -> SweepSpec:
    import dataclasses

    if not isinstance(rows, list):
        raise bad("paper", rows, "a list of tables: [[paper]] where = {...}, value = ...")
    figures = []
    for i, row in enumerate(rows):
        where = f"paper[{i}]"
        if not isinstance(row, dict):
            raise bad(where, row, "a table with 'where' and 'value'")
        _no_unknown(where, row, ("where", "value", "note"))
        match, value = row.get("where", {}), row.get("value")
        if not isinstance(match, dict) or not match:
            raise bad(f"{where}.where", match, "a non-empty table of {parameter name = value}")
        for name, v in match.items():
            param = next((p for p in spec.params if p.name == name), None)
            if param is None or param.random:
                listed = [p.name for p in spec.params if not p.random]
                raise bad(f"{where}.where", name, f"one of the listed parameters {listed}")
            listed = [p for p in param.values if same_value(p, v)]
            if not listed:
                raise bad(f"{where}.where.{name}", v, f"one of {list(param.values)}")
            match[name] = listed[0]
        if not _is_number(value):
            raise bad(f"{where}.value", value, "a number")
        figures.append(PaperFigure(dict(match), float(value), _string(row, "note", "")))
    return dataclasses.replace(spec, paper=tuple(figures))


def _table(data: dict, name: str) -> dict:
    value = data.get(name, {})
    if not isinstance(value, dict):
        raise bad(name, value, f"a table ([{name}])")
    return value


def _string(data: dict, name: str, default: str) -> str:
    value = data.get(name, default)
    if not isinstance(value, str):
        raise bad(name, value, "a string")
    return value


def _no_unknown(where: str, data: dict, allowed: tuple[str, ...]) -> None:
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        raise SweepError(f"{where}: unknown field {unknown[0]!r}; allowed: {list(allowed)}")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
