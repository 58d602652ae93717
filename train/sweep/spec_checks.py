"""What a sweep file's tables must agree on, checked once its ``SweepSpec`` is built (``spec.parse_sweep``): every
trial's training config resolves, the metric is a column the trials log, and the ``[[paper]]`` and
``[[more_seeds]]`` rows name configurations the parameters list. Each raises ``SweepError`` with the place in
the file and what is allowed; a claim against a baseline reads the stream its baseline played
(``check_baseline_pairs``). ``spec`` is a ``train.sweep.spec.SweepSpec`` (that module imports this one, not
the reverse)."""

from __future__ import annotations

import dataclasses
import itertools

from colorgrid.configkit import ConfigError
from train.config import TrainConfig, eval_stream
from train.sweep.checks import SUMMARY_SUFFIXES, SweepError, bad, same_value
from train.sweep.claim_spec import Baseline, parse_selection
from train.sweep.file import MoreSeeds, PaperFigure, written

MAX_COMBINATIONS = 10_000
"""The most grid combinations whose training configs ``check_configs`` builds."""


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
        totals.add(config.end_step)
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
    from train.metrics import EPISODE_TOTALS, episode_columns

    import numpy as np

    A = config.env.num_agents
    totals = {k: np.zeros((1, A)) for k in EPISODE_TOTALS}
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


def paper_figure(spec: SweepSpec, i: int, figure: PaperFigure) -> PaperFigure:
    """``[[paper]]`` row ``i`` with its configuration checked against the sweep's listed parameters (each value as
    the parameter lists it)."""
    where, match = f"paper[{i}]", {}
    for name, v in figure.where.items():
        param = next((p for p in spec.params if p.name == name), None)
        if param is None or param.random:
            listed = [p.name for p in spec.params if not p.random]
            raise bad(f"{where}.where", name, f"one of the listed parameters {listed}")
        listed = [p for p in param.values if same_value(p, v)]
        if not listed:
            raise bad(f"{where}.where.{name}", v, f"one of {list(param.values)}")
        match[name] = listed[0]
    return dataclasses.replace(figure, where=match, value=float(figure.value))


def more_seeds(spec: SweepSpec, i: int, more: MoreSeeds) -> MoreSeeds:
    """``[[more_seeds]]`` table ``i`` with its configurations checked against the sweep's listed parameters and its
    seeds against ``seeds``."""
    where = f"more_seeds[{i}]"
    again = [s for s in more.seeds if s in spec.seeds]
    if again:
        raise bad(f"{where}.seeds", written(more.seeds), f"seeds not already in 'seeds' {list(spec.seeds)} "
                                                         f"({again[0]} is)")
    listed = parse_selection(spec.params, f"{where}.where", {k: written(v) for k, v in more.where.items()})
    return dataclasses.replace(more, where=listed)


def check_baseline_pairs(spec: SweepSpec) -> None:
    """Each claim against a baseline (``b = { baseline = "<partner>/<policy>" }``) reads an evaluation column played
    beside the baseline's partner, so that a seed's arm and the baseline played the same episodes: the partner's own
    stream (``eval_astar/...`` for ``astar/copy``), or the main ``eval/...`` stream where side a's trials play beside
    the partner itself (``ippo-leader/copy`` for an arm trained beside ``ippo-leader``)."""
    for i, claim in enumerate(spec.claims):
        if not isinstance(claim.b, Baseline):
            continue
        stream = claim.metric.split("/")[0] if "/" in claim.metric else ""
        partner = claim.b.partner
        if stream == "eval":
            config = spec.config({**{p.name: p.values[0] for p in spec.params}, **claim.a}, spec.seeds[0])
            partners = [agent.policy for agent in config.agents if not agent.learns]
            if partner not in partners:
                raise bad(f"claim[{i}].b", claim.b.name, f"a baseline beside the partner side a's trials are "
                                                          f"evaluated beside on {claim.metric!r} ({partners or 'none'}),"
                                                          " or read the partner's own stream, eval_PARTNER/...")
        elif stream != f"eval_{partner}":
            raise bad(f"claim[{i}].metric", claim.metric, f"an evaluation column played beside the baseline's partner "
                                                          f"{partner!r}: eval_{partner}/..., or eval/... for an arm "
                                                          "trained beside it (a baseline is paired by evaluation seed)")
