"""The sweep file: what varies across a sweep's trials, and how they run (TOML, checked on load).

A sweep is a base training config (a preset and ``--set`` overrides, exactly as ``colorgrid
train`` takes them), parameters that vary over training-config keys, and seeds. Every grid
combination, times ``num_samples`` draws of the random parameters, times every seed is one
trial. The file's tables are declared in ``train.sweep.file`` and built by ``configkit.from_dict``; the
base and each trial's training config are resolved as ``colorgrid train`` resolves its own
(``train.config.resolve``). ``load_sweep`` raises ``SweepError`` with the place in the file and what is
allowed (``params (aux=-1.0): follower.aux_coef=-1.0 is invalid: a number >= 0``); what several tables must agree
on is checked in ``train.sweep.spec_checks``. See docs/SWEEPS.md.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from colorgrid.configkit import ConfigError, from_dict, read_toml, resolve_data
from train.config import TrainConfig, load_preset, parse_override, resolve
from train.sweep.checks import SweepError, bad
from train.sweep.claim_spec import Baseline, matches, parse_claims
from train.sweep.file import KINDS, RANDOM_KINDS, MoreSeeds, PaperFigure, ParamTable, Resources, Scheduler, SweepFile
from train.sweep.spec_checks import (check_baseline_pairs, check_configs, check_metric, more_seeds, paper_figure,
                                     summarised_columns)

NAME_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
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
    more_seeds: tuple[MoreSeeds, ...] = ()
    """Further seeds for some configurations (``[[more_seeds]]``, ``where`` as the parameters list their values)."""
    results: Path | None = None
    """A folder of finished trials' results kept with the project (``sweep publish`` writes it): ``sweep run``
    skips the trials whose results it holds, and ``sweep report`` reads them with the sweep's own."""
    baselines: tuple = ()
    """Baselines kept beside the results besides those the claims name (``claim_spec.Baseline``): rows to show
    beside the arms (``colorgrid sweep baselines`` evaluates both)."""
    description: str = ""
    pinned: dict[str, str] = field(default_factory=dict)
    """``[pinned]``: files the trials read, by path, each with the sha256 the verdicts are about."""
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
        lines = [line for param in self.params for line in param.overrides(values[param.name])]
        return resolve(self.base, {"seed": seed}, overrides=lines)

    def missing_files(self) -> list[str]:
        """``SETTING=PATH`` for each file a trial names that does not exist (a learner's ``init``; a frozen partner's
        checkpoint, population file, or a file named inside it: a person leader's base, a population's members;
        ``colorgrid.policies.policy_files``), read from the current folder as a trial reads it, over every
        configuration of the sweep."""
        from colorgrid.policies import policy_files

        configs = [self.config({**values, **sample}, self.seeds[0])
                   for values in self.configurations() for sample in self.samples()]
        missing = {}
        for config in configs:
            for role, agent in zip(config.env.roles, config.agents):
                named = ((f"{role}.init", agent.init), *((f"{role}.policy", path) for path in policy_files(agent.policy)),
                         *((f"{role}.policies", path) for spec in agent.policies for path in policy_files(spec)))
                missing.update({f"{key}={path}": None for key, path in named if path and not Path(path).exists()})
        return list(missing)

    def check_files(self) -> None:
        """Refuse, in one line, a sweep whose trials name checkpoint files that do not exist (``missing_files``):
        every trial would fail at its start; or whose pinned files (``[pinned]``) are missing or are not the ones
        pinned: its trials would train from another file than the one its verdicts are about."""
        missing = self.missing_files()
        if missing:
            raise SweepError(f"{self.path}: the trials name checkpoint files that do not exist (read from "
                             f"{Path.cwd()}): {', '.join(missing)}; make them first (the file's description may "
                             f"say how) or name others")
        for path, pinned in self.pinned.items():
            if not Path(path).is_file():
                raise SweepError(f"{self.path}: [pinned] {path} does not exist (read from {Path.cwd()}); make it "
                                 f"first (the file's description may say how): its sha256 must be {pinned}")
            with open(path, "rb") as f:  # (read each time: a file made again may keep its size and time)
                digest = hashlib.file_digest(f, "sha256").hexdigest()
            if digest != pinned:
                raise SweepError(f"{self.path}: [pinned] {path} has sha256 {digest}, not the {pinned} the file pins: "
                                 f"the file's trials and verdicts are about that one; a different file belongs in "
                                 f"a new sweep file")

    def configurations(self) -> list[dict]:
        """Every configuration of the grid: ``{parameter: value}`` for each combination of the listed values (the
        random parameters left out), in the order Ray Tune's grid gives them."""
        fixed = [p for p in self.params if not p.random]
        return [dict(zip((p.name for p in fixed), combo)) for combo in itertools.product(*(p.values for p in fixed))]

    def grid_size(self) -> int:
        return math.prod(len(p.values) for p in self.params if not p.random)

    @property
    def all_seeds(self) -> tuple[int, ...]:
        """``seeds``, then each ``[[more_seeds]]`` seed: every seed some configuration trains with."""
        return tuple(dict.fromkeys((*self.seeds, *(s for more in self.more_seeds for s in more.seeds))))

    def seeds_for(self, values: dict) -> tuple[int, ...]:
        """The seeds of the configuration with parameter ``values``: ``seeds``, and those of every
        ``[[more_seeds]]`` table whose ``where`` it matches."""
        extra = (s for more in self.more_seeds if matches(more.where, values) for s in more.seeds)
        return tuple(dict.fromkeys((*self.seeds, *extra)))

    def key(self, params: dict) -> tuple[str, int]:
        """What identifies a trial across folders and machines: its configuration's label and its seed."""
        return self.label(self.values(params)), int(params["seed"])

    def wants(self, params: dict) -> bool:
        """Whether the sweep trains this trial (a seed of ``all_seeds`` only some configurations take)."""
        return int(params["seed"]) in self.seeds_for(self.values(params))

    def num_trials(self) -> int:
        return self.num_samples * sum(len(self.seeds_for(values)) for values in self.configurations())

    def summary(self) -> str:
        extra = self.num_trials() - self.grid_size() * self.num_samples * len(self.seeds)
        configurations, seeds = self.grid_size() * self.num_samples, len(self.seeds)
        return (f"{self.num_trials()} trial{'s' * (self.num_trials() != 1)} ({configurations} "
                f"configuration{'s' * (configurations != 1)} x {seeds} seed{'s' * (seeds != 1)}"
                + (f", and {extra} more where [[more_seeds]] adds seeds" if extra else "") + ")")

    def same_trials(self, other: "SweepSpec") -> bool:
        """Whether ``other`` trains each trial the two share as this one does (the same base config,
        parameters and random draws; seeds, claims and words may differ): a sweep's folder may take the other
        file. The draws are seeded by the file's text, so with random parameters any change to the file makes
        other trials."""
        mine, theirs = self.resources, other.resources  # threads and device (train.sweep.trial.trial_config)
        return (self.base == other.base and self.params == other.params and self.samples() == other.samples()
                and (mine.cpus_per_trial, mine.gpus_per_trial) == (theirs.cpus_per_trial, theirs.gpus_per_trial))

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


def grid(spec: SweepSpec) -> list[dict]:
    """Every trial's parameters as Ray Tune's grid gives them (``seed``, each listed value or option by name, and
    the random parameters' draw as ``sample``), seed by seed: a sweep stopped partway has run every configuration's
    first seeds, and the ``[[more_seeds]]`` trials come last."""
    random = any(p.random for p in spec.params)
    trials = []
    for seed in spec.all_seeds:
        for sample in spec.samples():
            for values in spec.configurations():
                params = {"seed": seed, **values}
                if random:
                    params["sample"] = sample
                if spec.wants(params):
                    trials.append(params)
    return trials


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
    try:
        if not path.is_file():
            raise SweepError("no such sweep file")
        text = path.read_text()
        return parse_sweep(read_toml(path, "sweep file"), path, text, out)
    except ConfigError as err:
        raise SweepError(f"{path}: {err}") from None


def parse_sweep(data: dict, path: Path, text: str = "", out: str | Path | None = None) -> SweepSpec:
    """The checked ``SweepSpec`` of a sweep file's plain data: its tables built (``SweepFile``), then what takes
    several of them at once checked: parameters, the trials' training configs, the metric, figures and claims."""
    file = from_dict(SweepFile, data)
    params = tuple(parse_param(name, value) for name, value in file.params.items())
    owners: dict[str, str] = {}
    for param in params:
        for key in {*param.keys, *(k for o in param.options.values() for k in o)}:
            if key in owners:
                raise bad(f"params.{param.name}", key, f"a key no other parameter sets (params.{owners[key]} "
                                                       f"sets it too)")
            owners[key] = param.name
    if file.num_samples > 1 and not any(p.random for p in params):
        raise bad("num_samples", file.num_samples, "1 unless a parameter is random (choice, uniform, loguniform)")
    spec = SweepSpec(
        name=path.stem, path=path, base=base_config(file), seeds=file.seeds, params=params, metric=file.metric,
        mode=file.mode, final_window=file.final_window, num_samples=file.num_samples,
        out=Path(out if out is not None else file.out or f"runs/sweeps/{path.stem}"), resources=file.resources,
        scheduler=file.scheduler, description=file.description, text=text,
        results=Path(file.results) if file.results else None,
        baselines=tuple(Baseline(name) for name in file.baselines), pinned=dict(file.pinned))
    check_configs(spec)
    check_metric(spec)
    spec = dataclasses.replace(spec, paper=tuple(paper_figure(spec, i, row) for i, row in enumerate(file.paper)),
                               more_seeds=tuple(more_seeds(spec, i, row) for i, row in enumerate(file.more_seeds)))
    spec = dataclasses.replace(spec, claims=parse_claims(spec.params, spec.metric, summarised_columns(spec),
                                                         file.claim))
    check_baseline_pairs(spec)
    return spec


def base_config(file: SweepFile) -> dict:
    """The sweep's base training config as plain data: its preset, then its ``set`` lines (any key but ``seed``)."""
    for i, line in enumerate(file.set):
        if "=" in line and line.split("=", 1)[0].strip() == "seed":
            raise bad(f"set[{i}]", line, "any training key but seed (the sweep's seeds set it)")
    try:
        preset = load_preset(file.preset)
    except ConfigError as err:
        raise SweepError(f"preset: {err}") from None
    base = resolve_data(preset, overrides=file.set, cls=TrainConfig, where="set",
                        example="ppo.lr=3e-4 or follower.net.lstm=true")
    try:
        resolve(base)
    except ConfigError as err:
        raise SweepError(f"preset {file.preset!r} with set: {err}") from None
    return {k: v for k, v in base.items() if k != "description"}


def parse_param(name: str, value) -> Param:
    """One ``[params.NAME]`` table (or the short form ``NAME = [values]``: a grid over the training key NAME)."""
    where = f"params.{name}"
    if not NAME_PATTERN.match(name) or name in RESERVED:
        raise bad("params", name, f"names of 1 to 64 letters, digits, '_', '.' or '-', other than {list(RESERVED)}")
    if isinstance(value, list):  # the short form: a training key and its values
        value = {"grid": value}
    if not isinstance(value, dict):
        raise bad(where, value, f"a list of values, or a table with one of {list(KINDS)}")
    try:
        table = from_dict(ParamTable, value, where)
    except ConfigError as err:
        raise SweepError(str(err) if str(err).startswith(where) else f"{where}: {err}") from None
    kind = table.kinds[0]
    if kind == "options":
        for label, settings in table.options.items():
            for key in settings:
                _check_key(f"{where}.options.{label}", key)
        return Param(name, kind, tuple(table.options), (), {label: dict(s) for label, s in table.options.items()})
    for key in table.keys or (name,):
        _check_key(f"{where}.keys" if table.keys is not None else where, key)
    values = getattr(table, kind)
    if kind in RANDOM_KINDS[1:]:
        values = (float(values[0]), float(values[1]))
    return Param(name, kind, values, table.keys or (name,))


def _check_key(where: str, key: str) -> None:
    if key == "seed":
        raise bad(where, key, "any training key but seed (list seeds in 'seeds')")
    probe = f"{key}=0"
    try:
        parse_override(probe)
    except ConfigError as err:
        raise SweepError(f"{where}: {str(err).replace(f' in {probe!r}', '')}") from None
