"""Run a sweep on Ray Tune: a local Ray instance by default, or a cluster (``address``); resume one.

The sweep's folder holds the sweep file as read (``sweep.toml``), Tune's experiment state and
one folder per trial (Tune's ``result.json`` and ``params.json``, its checkpoints, and the
training run under ``run/``). A trial that crashes or loses its node is restarted from its last
checkpoint (``FailureConfig``); a sweep stopped by Ctrl+C or a lost driver is finished by
``resume_sweep`` (``Tuner.restore``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
import time
from pathlib import Path

import ray
from ray import tune

from train.sweep.declared import declare
from train.sweep.local import LOCAL_FILE, trial_packs
from train.sweep.spec import SPEC_FILE, WORKDIR_FILE, SweepError, SweepSpec, grid, load_folder
from train.sweep.trial import PACK, run_trial, trial_folder

MAX_FAILURES = 3
"""Restarts of a trial from its last checkpoint before it counts as failed."""


def connect(address: str | None, num_cpus: int | None = None) -> None:
    """Join the cluster at ``address``, or start a local Ray instance (no dashboard, every CPU); a Ray already
    started in this process is used as it is."""
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # with verbose=0: no tables of Tune's own; ProgressLines speaks
    # short trials checkpoint often; Tune's advice to checkpoint less is not for a sweep file to act on
    os.environ.setdefault("TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S", "0")
    # Tune warns of every trial without results yet when it saves an interrupted sweep: those are expected
    logging.getLogger("ray.tune.analysis.experiment_analysis").setLevel(logging.ERROR)
    if ray.is_initialized():
        return
    if address:
        if ":" in address and "://" not in address:  # HOST:PORT; 'auto' is found (and its token used) by ray.init
            check_cluster(address)
        ray.init(address=address, logging_level="WARNING", log_to_driver=False)
    else:  # num_cpus None: Ray counts the CPUs this process may use (container limits included)
        ray.init(num_cpus=num_cpus, include_dashboard=False, logging_level="WARNING", log_to_driver=False)


def check_cluster(address: str) -> None:
    """Ask the cluster at ``address`` for its id once, as ``ray.init`` would (with this process's token when
    ``RAY_AUTH_MODE=token``). A refusal, no answer, or authentication off there but on here is one line naming the
    cause and the fix, instead of Ray's twenty retries (minutes of them where nothing listens) and "Failed to
    connect to Ray cluster", or trials whose workers die before they start.

    Ray 2.60 sends a token to ``HOST:PORT`` only with ``RAY_AUTH_MODE=token``, but ``ray start --head`` turns
    token authentication on by itself where it finds a token (``~/.ray/auth_token``, which any local ``ray.init``
    writes): docs/SWEEPS.md, "A cluster"."""
    import grpc
    from ray._private.authentication.authentication_utils import is_token_auth_enabled
    from ray._private.grpc_utils import init_grpc_channel
    from ray._raylet import AuthenticationTokenLoader
    from ray.core.generated import gcs_service_pb2, gcs_service_pb2_grpc

    def ask(channel) -> tuple[grpc.StatusCode, str]:
        with channel:
            try:
                gcs_service_pb2_grpc.NodeInfoGcsServiceStub(channel).GetClusterId(
                    gcs_service_pb2.GetClusterIdRequest(), timeout=10)
                return grpc.StatusCode.OK, ""
            except grpc.RpcError as err:
                return err.code(), (err.details() or "").rsplit(": ", 1)[-1]

    copy, see = "copy the head's ~/.ray/auth_token to ~/.ray/auth_token here", "; see docs/SWEEPS.md, 'A cluster'"
    token_mode = is_token_auth_enabled()
    # Ray's token loader is asked only in token mode: once it has read a token, this process's own gRPC server
    # demands that token of every caller, even with authentication off, and the cluster's workers send none
    if token_mode and not AuthenticationTokenLoader.instance().has_token(ignore_auth_mode=True):
        raise SweepError(f"RAY_AUTH_MODE=token but this machine has no Ray token to show {address}: {copy}{see}")
    code, why = ask(init_grpc_channel(address))  # with the token in token mode, as ray.init asks
    if code == grpc.StatusCode.OK:
        if token_mode and ask(grpc.insecure_channel(address))[0] == grpc.StatusCode.OK:
            raise SweepError(f"the Ray cluster at {address} has token authentication off, and with RAY_AUTH_MODE="
                             f"token this process would refuse its workers' calls: unset RAY_AUTH_MODE here, or "
                             f"start every node with RAY_AUTH_MODE=token{see}")
        return
    if code in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED):
        raise SweepError(f"no Ray cluster answers at {address} ({why}): start one there with ray start --head, "
                         f"or check the address{see}")
    if code != grpc.StatusCode.UNAUTHENTICATED:
        return  # ray.init says what else is wrong
    if token_mode:  # Ray reads the token from the first of these that is set
        source = ("RAY_AUTH_TOKEN" if os.environ.get("RAY_AUTH_TOKEN") else
                  os.environ.get("RAY_AUTH_TOKEN_PATH") or "~/.ray/auth_token")
        raise SweepError(f"the Ray cluster at {address} refused this machine's token (from {source}): it is not "
                         f"the head's; {copy}" + (", and unset RAY_AUTH_TOKEN" if source == "RAY_AUTH_TOKEN" else "")
                         + see)
    raise SweepError(f"the Ray cluster at {address} wants a token and this process sends none (RAY_AUTH_MODE is "
                     f"not 'token'): run with RAY_AUTH_MODE=token and the head's token here (its ~/.ray/auth_token in "
                     f"~/.ray/auth_token), or start every node with RAY_AUTH_MODE=disabled (a private network only)"
                     f"{see}")


def check_resources(spec: SweepSpec) -> None:
    """A trial that asks for more than any node has would wait for ever: say so in one line instead."""
    nodes = [n["Resources"] for n in ray.nodes() if n.get("Alive")]
    for kind, wanted in (("CPU", spec.resources.cpus_per_trial), ("GPU", spec.resources.gpus_per_trial)):
        most = max((n.get(kind, 0) for n in nodes), default=0)
        if wanted > most:
            raise SweepError(f"resources: a trial asks for {wanted:g} {kind}s but the largest node of this Ray "
                             f"cluster has {most:g}; lower [resources] or join a larger cluster (--address)")


def param_space(spec: SweepSpec, kept: frozenset = frozenset()) -> dict:
    """Every seed, listed value and option is a grid axis; the random parameters' draws are one more axis
    (``sample``), drawn once, so that the seeds of a configuration share its draw. The seeds are ``all_seeds``:
    a trial of a ``[[more_seeds]]`` seed its configuration does not take ends at once (``run_trial``).

    With ``[resources] pack`` above 1, the one axis is the packs (``pack``): the trials not ``kept``, in packs
    of trials whose shapes agree (``train.sweep.local.trial_packs``), each a Tune trial."""
    if spec.resources.pack > 1:
        packs = trial_packs(spec, [params for params in grid(spec) if spec.key(params) not in kept])
        if packs:  # (every trial kept: the grid below, whose trials end at once as kept)
            return {PACK: tune.grid_search(packs)}
    space = {"seed": tune.grid_search(list(spec.all_seeds))}
    for param in spec.params:
        if not param.random:
            space[param.name] = tune.grid_search(list(param.values))
    if any(p.random for p in spec.params):
        space["sample"] = tune.grid_search(spec.samples())
    return space


def scheduler(spec: SweepSpec):
    if spec.scheduler.kind == "none":
        return None
    from ray.tune.schedulers import ASHAScheduler

    total = spec.config({p.name: p.values[0] for p in spec.params}, spec.seeds[0]).total_steps
    grace = spec.scheduler.grace_period or max(1, total // 10)
    return ASHAScheduler(time_attr="step", max_t=total, grace_period=grace,
                         reduction_factor=spec.scheduler.reduction_factor)


def trainable(spec: SweepSpec, workdir: str | None = None, kept: frozenset = frozenset()):
    """Tune's trainable for ``spec``; a trial whose (configuration, seed) is in ``kept`` (its results are in
    the sweep's results folder) ends at once."""
    resources = {"cpu": spec.resources.cpus_per_trial, "gpu": spec.resources.gpus_per_trial}
    spec = dataclasses.replace(spec, out=spec.out.resolve())  # trials write their run folders there
    return tune.with_resources(tune.with_parameters(run_trial, spec=spec, workdir=workdir or os.getcwd(),
                                                    kept=kept), resources)


def kept_trials(spec: SweepSpec, folder: Path | None = None) -> frozenset:
    """The trials whose results the sweep's results folder keeps, said in a line when there are any."""
    from train.sweep.results import committed_keys, results_folder

    kept = frozenset(committed_keys(spec, folder))
    if kept:
        print(f"{len(kept)} of {spec.num_trials()} trials are kept in {results_folder(spec, folder)}: "
              f"they are not run again", flush=True)
    return kept


def trial_label(spec: SweepSpec, params: dict) -> str:
    """How a line names a Tune trial: its configuration and seed, or a pack's trials in turn."""
    if PACK in params:
        return f"pack of {len(params[PACK])}: " + "; ".join(trial_label(spec, p) for p in params[PACK])
    return f"{spec.label(spec.values(params))}, seed={params.get('seed')}"


def run_config(spec: SweepSpec, folder: Path):
    return tune.RunConfig(
        name=folder.name, storage_path=str(folder.parent), verbose=0, callbacks=[ProgressLines(spec)],
        failure_config=tune.FailureConfig(max_failures=MAX_FAILURES),
        checkpoint_config=tune.CheckpointConfig(num_to_keep=2))


def run_sweep(spec: SweepSpec, address: str | None = None, num_cpus: int | None = None) -> int:
    """Run every trial of ``spec`` into ``spec.out``; returns the exit status (0: every trial finished)."""
    folder = spec.out.resolve()
    if (folder / SPEC_FILE).exists() and tune.Tuner.can_restore(str(folder)):
        raise SweepError(f"{folder} already holds a sweep; finish it with colorgrid sweep resume {spec.out}, or "
                         f"choose another --out")
    if (folder / LOCAL_FILE).exists():
        raise SweepError(f"{folder} holds a sweep run without Ray (--local); continue it with colorgrid sweep run "
                         f"{spec.path} --local N, or choose another --out")
    spec.check_files()
    if spec.resources.pack > 1 and spec.scheduler.kind != "none":
        raise SweepError(f"[resources] pack = {spec.resources.pack} with [scheduler] kind = "
                         f"{spec.scheduler.kind!r}: a scheduler stops trials one by one and a pack trains its "
                         f"trials as one; use pack = 1 with a scheduler")
    connect(address, num_cpus)
    check_resources(spec)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / SPEC_FILE).write_text(spec.text)
    (folder / WORKDIR_FILE).write_text(os.getcwd())
    declare(spec, folder)  # each claim's digest, before the first trial starts (train/sweep/declared.py)
    concurrent = spec.resources.max_concurrent or None
    print(f"sweep {spec.name}: {spec.summary()} into {folder}", flush=True)
    kept = kept_trials(spec)
    tuner = tune.Tuner(
        trainable(spec, kept=kept), param_space=param_space(spec, kept),
        tune_config=tune.TuneConfig(metric=spec.metric, mode=spec.mode, scheduler=scheduler(spec),
                                    max_concurrent_trials=concurrent, trial_dirname_creator=trial_folder_name,
                                    reuse_actors=True),  # a worker process imports torch and compiles once
        run_config=run_config(spec, folder))
    return finish(tuner, spec, folder)


def resume_sweep(folder: str | Path, address: str | None = None, num_cpus: int | None = None) -> int:
    """Finish the sweep in ``folder``: trials that did not end are continued from their last checkpoints."""
    folder = Path(folder).resolve()
    spec = load_folder(folder)
    if not tune.Tuner.can_restore(str(folder)):
        raise SweepError(f"{folder}: Ray Tune saved no experiment state here yet; start it again with "
                         f"colorgrid sweep run")
    workdir = (folder / WORKDIR_FILE).read_text() if (folder / WORKDIR_FILE).exists() else os.getcwd()
    connect(address, num_cpus)
    check_resources(spec)
    print(f"resuming sweep {folder.name} in {folder}", flush=True)
    tuner = tune.Tuner.restore(str(folder), trainable=trainable(spec, workdir, kept_trials(spec, folder)),
                               resume_unfinished=True,
                               resume_errored=True)
    return finish(tuner, spec, folder)


def finish(tuner, spec: SweepSpec, folder: Path) -> int:
    from train.sweep.results import collect

    grid = tuner.fit()
    trials, _ = collect(folder)
    ended = ended_trials(folder, spec)
    done = int(trials["finished"].sum()) if len(trials) else 0
    early = ended - done - grid.num_errors  # ended on disk without reaching the end: the scheduler stopped them
    print(f"sweep {folder.name}: {done} of {spec.num_trials()} trials ran to the end"
          + (f", {early} stopped early by the scheduler" if early > 0 else "")
          + (f", {grid.num_errors} failed" if grid.num_errors else "") + f"; tables in {folder}", flush=True)
    if ended < spec.num_trials():
        print(f"stopped before its end; finish it with: colorgrid sweep resume {folder}", flush=True)
        return 130
    if grid.num_errors:
        print(f"first failure: {first_line(grid.errors[0])}", file=sys.stderr)
        return 1
    print(f"report: colorgrid sweep report {folder}", flush=True)
    return 0


def ended_trials(folder: Path, spec: SweepSpec) -> int:
    """Trials of the sweep that the experiment state saved on disk counts as ended (finished, stopped by the
    scheduler or failed); not Tune's trials of a ``[[more_seeds]]`` seed their configuration does not take, which
    end at once. After Ctrl+C Tune saves the state before it stops the running trials, so those count as not
    ended there, and ``Tuner.restore`` continues them. A pack's trials count one by one, with the trials kept in
    the results folder (a packed sweep makes no Tune trial of them)."""
    from train.sweep.results import committed_keys

    analysis = tune.ExperimentAnalysis(str(folder))
    ended = [t.config for t in analysis.trials if t.status in ("TERMINATED", "ERROR")]
    if not any(PACK in config for config in ended):
        return sum(map(spec.wants, ended))
    keys = {spec.key(params) for config in ended for params in config.get(PACK, [config]) if spec.wants(params)}
    return len(keys | committed_keys(spec, folder))


def first_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    lines = [line for line in text if line.strip()]
    return lines[-1] if lines else type(error).__name__


def trial_folder_name(trial) -> str:
    return trial_folder(trial.trial_id)


class ProgressLines(tune.Callback):
    """One line per trial as it goes (at most every ``every`` seconds each), and one when it ends."""

    def __init__(self, spec: SweepSpec, every: float = 30.0):
        self.spec, self.every = spec, every
        self.shown: dict[str, float] = {}

    def _line(self, trial, result: dict, what: str) -> str:
        value = result.get(self.spec.metric)
        total = result.get("total_steps") or 0
        step = result.get("step") or 0
        return (f"{what} [{trial_label(self.spec, trial.config)}] step {int(step):,}/{int(total):,} "
                f"{self.spec.metric} {value:+.2f}" if isinstance(value, float) else f"{what} "
                f"[{trial_label(self.spec, trial.config)}] step {int(step):,}")

    def on_trial_result(self, iteration, trials, trial, result, **info):
        if result.get("skipped"):
            return
        now = time.monotonic()
        if now - self.shown.get(trial.trial_id, -1e9) >= self.every:
            self.shown[trial.trial_id] = now
            sps = result.get("sps")
            print(self._line(trial, result, "trial") + (f", {sps:,.0f} steps/s" if sps else ""), flush=True)

    def on_trial_complete(self, iteration, trials, trial, **info):
        result = trial.last_result or {}
        if result.get("skipped"):  # a [[more_seeds]] seed of another configuration: not a trial of the sweep
            return
        print(self._line(trial, result, "kept (not run again)" if result.get("kept") else "ended"), flush=True)

    def on_trial_error(self, iteration, trials, trial, **info):
        print(f"failed [{trial_label(self.spec, trial.config)}]: see {Path(trial.path) / 'error.txt'}", flush=True)
