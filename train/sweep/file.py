"""The sweep file's tables, declared: frozen dataclasses validated on construction, built from the TOML's plain data
by ``configkit.from_dict`` as every config of the project is (the study file's too).

``SweepFile`` is the file as written, each field checked on its own (``seeds=[1, 1] is invalid: ...``,
``resources.cpus_per_trial=0 is invalid: ...``, ``params.aux: unknown field 'gird'``); ``ParamTable`` is one
``[params.NAME]`` table. What needs several fields at once (the training configs the trials build, the metric,
the paper's figures and claims against the parameters) is checked by ``train.sweep.spec.parse_sweep``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from colorgrid.configkit import (ConfigBase, ConfigError, check_choice, check_int, check_number, fail, is_int,
                                 is_number)
from train.sweep.claim_spec import Direction

GRID_KINDS = ("grid", "options")
RANDOM_KINDS = ("choice", "uniform", "loguniform")
KINDS = GRID_KINDS + RANDOM_KINDS
MODES = ("max", "min")
SCHEDULERS = ("none", "asha")
SHA256 = re.compile(r"[0-9a-f]{64}")



def written(value: Any) -> Any:
    """A value as the file writes it (lists, not the tuples the dataclasses hold), for messages."""
    if isinstance(value, tuple):
        return [written(v) for v in value]
    return value


def refuse(owner, name: str, allowed: str) -> None:
    """``fail`` with the value as the file writes it: ``seeds=[1, 1] is invalid: ...``."""
    fail(owner, name, allowed, value=written(getattr(owner, name)))


def check_seeds(owner, example: str) -> None:
    """``owner.seeds`` is a non-empty list of distinct whole numbers >= 0 (``seeds``, ``[[more_seeds]] seeds``)."""
    seeds = owner.seeds
    if (not isinstance(seeds, tuple) or not seeds or not all(is_int(s) and s >= 0 for s in seeds)
            or len(set(seeds)) != len(seeds)):
        refuse(owner, "seeds", f"a list of distinct whole numbers >= 0, e.g. {example}")


class Table(ConfigBase):
    """What every table of the sweep file shares: how its errors read (the field first, as ``ConfigBase``'s)."""

    UNKNOWN_STYLE = "{where}: unknown field {first!r}; allowed: {allowed}"


@dataclass(frozen=True)
class Resources(Table):
    """``[resources]``: what each trial gets, and how many run at once."""

    cpus_per_trial: float = 1
    """CPU cores each trial gets; its torch and numba threads are limited to it (rounded up, at least 1)."""
    gpus_per_trial: float = 0
    """GPUs each trial gets (fractions share one); with any, the trials train on ``cuda``."""
    max_concurrent: int = 0
    """Trials at once (0: as many as the cluster's CPUs fit); with ``pack``, packs at once."""
    pack: int = 1
    """Trials trained as one in a process (``train.pack``): up to this many trials whose shapes agree
    (``train.packing.pack_key``) share a pack, which gets one trial's ``cpus_per_trial`` and ``gpus_per_trial``.
    Each trial is still kept, reported and resumed on its own; 1: every trial alone."""

    def __post_init__(self):
        check_number(self, "cpus_per_trial", "a number > 0", lambda v: v > 0)
        check_number(self, "gpus_per_trial", "a number >= 0", lambda v: v >= 0)
        check_int(self, "max_concurrent", 0, allowed="a whole number >= 0 (0: as many as fit)")
        check_int(self, "pack", 1, 4096, allowed="a whole number from 1 (every trial alone) to 4096")


@dataclass(frozen=True)
class Scheduler(Table):
    """``[scheduler]``: whether trials whose metric trails are stopped early."""

    kind: str = "none"
    """``none`` (every trial runs to the end) or ``asha`` (stops trials whose metric trails, at rungs)."""
    grace_period: int = 0
    """``asha``: env steps before a trial may be stopped (0: a tenth of ``total_steps``)."""
    reduction_factor: float = 3
    """``asha``: at each rung, the best 1/reduction_factor of trials go on."""

    def __post_init__(self):
        check_choice(self, "kind", SCHEDULERS, f"one of {list(SCHEDULERS)}")
        check_int(self, "grace_period", 0, allowed="a whole number of env steps >= 0 (0: a tenth of total_steps)")
        check_number(self, "reduction_factor", "a number > 1", lambda v: v > 1)
        if self.kind == "none" and (self.grace_period, self.reduction_factor) != (0, 3):
            raise ConfigError("scheduler: grace_period and reduction_factor need kind = 'asha'")


@dataclass(frozen=True)
class PaperFigure(Table):
    """A number the paper reports for one configuration, shown beside the sweep's own in its report."""

    where: dict
    """The configuration: ``{parameter name: value or option label}``."""
    value: float
    note: str = ""

    def __post_init__(self):
        if not isinstance(self.where, dict) or not self.where:
            refuse(self, "where", "a non-empty table of {parameter name = value}")
        check_number(self, "value", "a number")
        if not isinstance(self.note, str):
            refuse(self, "note", "a string")


@dataclass(frozen=True)
class MoreSeeds(Table):
    """``[[more_seeds]]``: seeds beyond ``seeds`` for some configurations only (those of claims that came out
    inconclusive or in direction only, say), so that a sweep grows where it has not decided instead of
    everywhere."""

    seeds: tuple[int, ...]
    where: dict
    """The configurations: ``{parameter name: value or option label, or a list of them}``."""
    note: str = ""
    """Why these configurations get more seeds, for people."""

    def __post_init__(self):
        check_seeds(self, "[3, 4]")
        if not isinstance(self.where, dict) or not self.where:
            refuse(self, "where", "a non-empty table of {parameter name = value or [values]}")
        if not isinstance(self.note, str):
            refuse(self, "note", "a string")


@dataclass(frozen=True)
class ClaimTable(Table):
    """``[[claim]]``: one of the paper's claims as written, each field checked on its own. What needs the file's
    parameters and metric (its sides, the column it compares, a name no other claim has) is checked by
    ``train.sweep.claim_spec.parse_claims``, which makes it a ``Claim``."""

    name: str | None = None
    """A short name, e.g. ``annealing helps`` (required)."""
    a: Any = None
    """Side a: ``{parameter = value or [values]}`` (required)."""
    b: Any = None
    """Side b: a table as ``a``, ``{ baseline = "<partner>/<policy>" }`` or a number (required)."""
    expect: str | None = None
    """The paper's direction: ``>`` (a above b), ``<`` (a below b) or ``~`` (no difference beyond ``margin``)."""
    margin: float | None = None
    """``~`` only (and required there): the largest difference that counts as none, in the metric's units."""
    metric: str | None = None
    """The final column compared (default: the sweep's metric)."""
    paper: str = ""
    """The paper's words (or figures) for the claim."""
    b_name: str = ""
    """What a constant or baseline side b is, for the report."""

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            refuse(self, "name", "a non-empty name no other claim has")
        if self.expect not in [d.value for d in Direction]:
            refuse(self, "expect", "'>' (a above b), '<' (a below b) or '~' (no difference beyond margin)")
        if self.expect == Direction.SAME:
            if not (is_number(self.margin) and self.margin > 0):
                fail(self, "margin", "a number > 0 in the metric's units (expect = '~' needs one)",
                     value=0.0 if self.margin is None else self.margin)
        elif self.margin is not None:
            refuse(self, "margin", "given only with expect = '~'")
        for text in ("paper", "b_name"):
            if not isinstance(getattr(self, text), str):
                refuse(self, text, "a string")


@dataclass(frozen=True)
class ParamTable(Table):
    """One ``[params.NAME]`` table: exactly one kind of values, and the training keys they set."""

    keys: tuple[str, ...] | None = None
    """Training-config keys (``ppo.lr``, ``follower.aux_coef``) the value sets (default: the parameter's name)."""
    grid: tuple | None = None
    """Listed values, each a configuration."""
    options: dict | None = None
    """Named bundles of settings: ``{label: {training key: value}}``."""
    choice: tuple | None = None
    """Values drawn at random."""
    uniform: tuple | None = None
    """``[low, high]``: drawn uniformly."""
    loguniform: tuple | None = None
    """``[low, high]``, ``0 < low``: drawn uniformly in log space."""

    def __post_init__(self):
        kinds = self.kinds
        if len(kinds) != 1:
            raise ConfigError(f"needs exactly one of {list(KINDS)}, found {kinds or 'none'}")
        kind, raw = kinds[0], getattr(self, kinds[0])
        if kind == "options":
            if self.keys is not None:
                raise ConfigError("'keys' is for listed or random values; each option names its own keys")
            if not isinstance(raw, dict) or not raw:
                refuse(self, "options", "a table of labels, each a table of {training key = value}")
            for label, settings in raw.items():
                if not isinstance(settings, dict):
                    fail(self, f"options.{label}", "a table of {training key = value} ({} for none)", value=settings)
            return
        if self.keys is not None and (not isinstance(self.keys, tuple) or not self.keys
                                      or not all(isinstance(k, str) for k in self.keys)):
            refuse(self, "keys", "a list of training keys, e.g. ['leader.aux_coef', 'follower.aux_coef']")
        if kind in ("grid", "choice"):
            if not isinstance(raw, tuple) or not raw:
                refuse(self, kind, "a non-empty list of values")
            if len({_json(v) for v in raw}) != len(raw):
                refuse(self, kind, "distinct values")
        elif (not isinstance(raw, tuple) or len(raw) != 2 or not all(is_number(v) for v in raw)
              or not raw[0] < raw[1] or (kind == "loguniform" and raw[0] <= 0)):
            refuse(self, kind, f"[low, high] with {'0 < low < high' if kind == 'loguniform' else 'low < high'}")

    @property
    def kinds(self) -> list[str]:
        """The kinds of values the table gives (one, once checked)."""
        return [k for k in KINDS if getattr(self, k) is not None]


@dataclass(frozen=True)
class SweepFile(Table):
    """A sweep file as written (see docs/SWEEPS.md), each field checked on its own."""

    description: str = ""
    """What the sweep asks, for people (its report shows it)."""
    preset: str = "default"
    """The base training preset (a name or a JSON file), as ``colorgrid train --preset`` takes it."""
    set: tuple[str, ...] = ()
    """``KEY=VALUE`` overrides of the base config, as ``colorgrid train --set`` takes them (not ``seed``)."""
    seeds: tuple[int, ...] = (0,)
    """Every configuration is trained once per seed."""
    more_seeds: tuple[MoreSeeds, ...] = ()
    """``[[more_seeds]]``: further seeds for the configurations each table names."""
    params: dict = field(default_factory=dict)
    """``[params.NAME]`` tables (or ``NAME = [values]``): what varies."""
    num_samples: int = 1
    """Draws of the random parameters per grid point."""
    metric: str = "team_reward"
    """The training-log column that ranks configurations."""
    mode: str = "max"
    """Whether a larger (``max``) or smaller (``min``) metric is better."""
    final_window: int = 10
    """The final value of a metric is its mean over the trial's last this many reports."""
    out: str = ""
    """Where the sweep's folder goes (default ``runs/sweeps/<file name>``)."""
    resources: Resources = field(default_factory=Resources)
    scheduler: Scheduler = field(default_factory=Scheduler)
    paper: tuple[PaperFigure, ...] = ()
    """``[[paper]]``: the paper's figures, shown beside the sweep's own."""
    claim: tuple[ClaimTable, ...] = ()
    """``[[claim]]``: the paper's claims to decide (``train.sweep.claim_spec``)."""
    results: str | None = None
    """A folder of finished trials' results kept with the project (``sweep publish`` writes it)."""
    baselines: tuple[str, ...] = ()
    """Baselines (``<partner>/<policy>``) kept beside the results besides those the claims name, to show beside the
    arms: ``colorgrid sweep baselines`` evaluates both into the results folder's ``baselines.json``."""
    pinned: dict = field(default_factory=dict)
    """``[pinned]``: ``"PATH" = "SHA256"`` for each file the trials read whose contents the verdicts are about (a
    warm start's checkpoint): ``sweep check``, ``sweep run`` and a resume refuse to start when one is missing or
    differs (``SweepSpec.check_files``)."""

    def __post_init__(self):
        for name in ("description", "preset", "out"):
            if not isinstance(getattr(self, name), str):
                refuse(self, name, "a string")
        if not isinstance(self.set, tuple) or not all(isinstance(s, str) for s in self.set):
            refuse(self, "set", "a list of KEY=VALUE strings, as colorgrid train --set takes them")
        check_seeds(self, "[0, 1, 2]")
        if not isinstance(self.params, dict):
            refuse(self, "params", "a table ([params])")
        check_int(self, "num_samples", 1, allowed="a whole number >= 1 (draws of the random parameters per grid "
                                                  "point)")
        check_choice(self, "mode", MODES, "'max' or 'min'")
        check_int(self, "final_window", 1, allowed="a whole number >= 1 (reports averaged for a final value)")
        for name in ("resources", "scheduler"):
            if not isinstance(getattr(self, name), Table):
                refuse(self, name, f"a table ([{name}])")
        if not isinstance(self.more_seeds, tuple):
            refuse(self, "more_seeds", "a list of tables: [[more_seeds]] seeds = [...], where = {...}")
        if not isinstance(self.paper, tuple):
            refuse(self, "paper", "a list of tables: [[paper]] where = {...}, value = ...")
        if not isinstance(self.claim, tuple):
            refuse(self, "claim", "a list of tables: [[claim]] name = ..., a = {...}, b = {...} or a number, "
                                  "expect = '>', '<' or '~'")
        if not isinstance(self.baselines, tuple) or not all(isinstance(b, str) for b in self.baselines):
            refuse(self, "baselines", "a list of '<partner>/<policy>' strings, e.g. ['astar/copy']")
        if not isinstance(self.pinned, dict) or not all(
                isinstance(path, str) and path.strip() and isinstance(digest, str) and SHA256.fullmatch(digest)
                for path, digest in self.pinned.items()):
            refuse(self, "pinned", 'a table of "PATH" = "SHA256" (64 lowercase hexadecimal digits, as sha256sum '
                                   'prints them)')
        if self.results is not None and (not isinstance(self.results, str) or not self.results.strip()):
            refuse(self, "results", "a folder for the finished trials' results, e.g. 'docs/reproduction/x'")


def _json(value) -> str:
    import json

    return json.dumps(written(value))
