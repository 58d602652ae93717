"""Checkpoint files: weights, optimizer, configs, step and the trainer's state for exact resumption.

Layout (``torch.save`` of plain containers, loadable with ``weights_only=True``)::

    format: "colorgrid-ippo", version: 1
    config: the TrainConfig as a dict        env_config: the EnvConfig as a dict
    step, iteration                          agents: {name: entry | None}
    entry: {"net": NetConfig dict, "agent_index", "state_dict", "optimizer" (or None when exported)},
           and "agents" (the indices it plays) for a network shared within a role, and "temperature"
           (how it acts unless told otherwise: 1 samples as trained, 0 is greedy) when exported with one

``agents`` has one key per network, named after its agent (``env.agent_names``: ``leader`` and
``follower`` in the 1:1 team) or, for a network shared within a role, after the role; an agent
that did not learn appears under its own name with None.
    trainer_state: tensors and plain values (format 2: env state, last step's inputs, recurrent states,
                   partners' state_dicts, RNG states), or None when exported

Nothing in a checkpoint is pickled: resuming a run is as safe as loading its weights. A trainer's
checkpoint is written by ``trainer_payload`` and read back by ``restore_trainer``.
"""

from __future__ import annotations

import dataclasses
import enum
import io
import pickle
import zipfile
from pathlib import Path

import numpy as np
import torch

from colorgrid.config import ROLES, EnvConfig
from colorgrid.configkit import from_dict
from colorgrid.files import atomic_path
from colorgrid.replay import describe_agent
from colorgrid.replay.format import pin_checkpoints
from colorgrid.state import EnvState
from train.acting import ACTING
from train.config import NetConfig, TrainConfigError
from train.nets import ActorCritic

FORMAT, VERSION = "colorgrid-ippo", 1


def agent_entry(model: ActorCritic, optimizer: torch.optim.Optimizer | None) -> dict:
    entry = {"net": dataclasses.asdict(model.net), "agent_index": model.agent_index,
             "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
             "optimizer": optimizer.state_dict() if optimizer is not None else None}
    if model.shared:
        entry["agents"] = list(model.agents)
    return entry


def network_agents(entry: dict) -> tuple[int, ...]:
    """The agent indices a checkpoint entry's network plays."""
    return tuple(int(a) for a in entry["agents"]) if "agents" in entry else (int(entry["agent_index"]),)


def find_network(ckpt: dict, env: EnvConfig, name: str | None, what: str) -> tuple[str, dict]:
    """``(key, entry)`` of the network that plays ``name`` in a checkpoint (``env``: its team).

    ``name`` is a key of ``ckpt["agents"]`` (an agent's name, or a role whose agents share a
    network), an agent's name (``follower_1``: the network it plays, its own or its role's), a
    role (``follower``: the role's only network), or None (the only network).
    """
    trained = {key: entry for key, entry in ckpt["agents"].items() if entry is not None}
    if name is None:
        if len(trained) != 1:
            raise ValueError(f"{what} holds trained agents {sorted(trained)}; say which one to load")
        return next(iter(trained.items()))
    if name in trained:
        return name, trained[name]
    if name not in env.agent_names and name not in ROLES:  # e.g. a 1:1 network asked to play in a team
        raise ValueError(f"{what} was trained in a team of {env.num_leaders} leader(s) and {env.num_followers} "
                         f"follower(s), whose agents are {list(env.agent_names)}: it has no {name}")
    plays = {key: network_agents(entry) for key, entry in trained.items()}
    found = []
    if name in env.agent_names:
        found = [key for key, agents in plays.items() if env.agent_names.index(name) in agents]
    elif name in ROLES:
        found = [key for key, agents in plays.items() if any(env.roles[a] == name for a in agents)]
    if len(found) > 1:
        raise ValueError(f"{what} holds several trained {name}s ({', '.join(found)}); say which one to load")
    if not found:
        raise ValueError(f"{what} holds no trained {name} (it has: {sorted(trained) or 'none'})")
    return found[0], trained[found[0]]


def save_checkpoint(path: str | Path, payload: dict) -> Path:
    """Write atomically (a crash mid-write never leaves a truncated checkpoint)."""
    payload = without_enums({"format": FORMAT, "version": VERSION, **payload})
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buffer.getvalue())
    return path


def load_checkpoint(path: str | Path) -> dict:
    """Read a checkpoint (tensors and plain containers only); every problem raises one clear line."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    if not path.is_file():
        kind = "a directory" if path.is_dir() else "not a regular file"
        raise ValueError(f"{path} is not a readable ColorGrid checkpoint: it is {kind}")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file
        raise ValueError(f"{path} is not a readable ColorGrid checkpoint: {_unreadable_reason(path, err)}") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise ValueError(f"{path} is not a ColorGrid trainer checkpoint (format {FORMAT!r})")
    if ckpt.get("version") != VERSION:
        raise ValueError(f"{path} has checkpoint version {ckpt.get('version')!r}; this trainer reads {VERSION}")
    for key in ("agents", "env_config", "config", "step"):
        if key not in ckpt:
            raise ValueError(f"{path} lacks {key!r}; it is not a complete checkpoint")
    agents = ckpt["agents"]
    if not (isinstance(agents, dict) and all(isinstance(e, dict) or e is None for e in agents.values())
            and isinstance(ckpt["env_config"], dict) and isinstance(ckpt["config"], dict)
            and isinstance(ckpt["step"], int)):
        raise ValueError(f"{path} is a damaged checkpoint: agents, env_config or config is not a mapping, "
                         f"or step is not an integer")
    return ckpt


def _unreadable_reason(path: Path, err: Exception) -> str:
    """Why torch could not load ``path``, in one line (torch's own messages run to many lines of advice)."""
    if path.stat().st_size == 0:
        return "the file is empty"
    if not zipfile.is_zipfile(path):
        return "it is not a file written by torch.save (truncated, corrupt, or another kind of file)"
    if isinstance(err, pickle.UnpicklingError):
        return "it holds objects other than tensors and plain containers, which ColorGrid checkpoints never do"
    first_line = str(err).strip().splitlines()[0][:200] if str(err).strip() else ""
    return f"its archive is damaged ({type(err).__name__}: {first_line})"


def build_model(entry: dict, env: EnvConfig, what: str) -> ActorCritic:
    """Rebuild a network from a checkpoint entry, with a clear error when the weights do not fit.

    Building it leaves torch's global random generator as it was: a run's fresh networks are then
    initialised the same whether a partner's checkpoint was read from disk or found already loaded
    (``ModelCache``), and whether or not a run loads any.
    """
    try:
        net = from_dict(NetConfig, entry["net"], "net")
    except TrainConfigError as err:
        raise ValueError(f"{what}: {err}") from None
    agents = network_agents(entry)
    with torch.random.fork_rng(devices=[]):  # the weights are overwritten: their random init must not move
        model = ActorCritic(net, env, agents if len(agents) > 1 else agents[0])  # torch's generator (see below)
    load_weights(model, entry["state_dict"], what)
    model.acting = {k: check(entry[k], what) for k, (check, _) in ACTING.items() if k in entry}  # how it says to act
    return model


def load_weights(model: ActorCritic, state_dict: dict, what: str) -> None:
    own = model.state_dict()
    missing = sorted(set(own) - set(state_dict))
    extra = sorted(set(state_dict) - set(own))
    shapes = [f"{k}: checkpoint {tuple(state_dict[k].shape)}, network {tuple(own[k].shape)}"
              for k in own if k in state_dict and own[k].shape != state_dict[k].shape]
    if missing or extra or shapes:
        players = ", ".join(model.env.agent_names[a] for a in model.agents)
        raise ValueError(f"{what} does not match the network {model.net} for the {players}: "
                         f"missing {missing[:4]}, unexpected {extra[:4]}, shape mismatches {shapes[:4]}")
    model.load_state_dict(state_dict)


def export_agent(src: str | Path, role: str, dst: str | Path, temperature: float | None = None,
                 min_belief: float | None = None) -> Path:
    """Keep only one network's weights and configs (no optimizer, no trainer state): a small file to ship.
    ``role`` names it as ``find_network`` takes it (an agent's name, or a role). ``temperature`` and
    ``min_belief`` (``train.policy.NetPolicy``) are stored as how the network acts wherever the file (or a
    shipped name for it) is loaded without them; None keeps the source's (by default sampling as trained,
    every move allowed)."""
    ckpt = load_checkpoint(src)
    key, entry = find_network(ckpt, EnvConfig.from_dict(ckpt["env_config"]), role, str(src))
    agents = {name: None for name in ckpt["agents"]}
    agents[key] = {**entry, "optimizer": None}
    for name, value in (("temperature", temperature), ("min_belief", min_belief)):
        if value is not None:
            agents[key][name] = ACTING[name][0](value, f"--{name.replace('_', '-')}")
    return save_checkpoint(dst, {"config": ckpt["config"], "env_config": ckpt["env_config"], "step": ckpt["step"],
                                 "iteration": ckpt.get("iteration"), "wall_time_s": ckpt.get("wall_time_s"),
                                 "device": ckpt.get("device"), "agents": agents, "trainer_state": None})


def without_enums(obj):
    """``obj`` with every enum member (a ``Role`` as a key or a value) its plain value: ``weights_only=True`` loads
    no class but the plain containers, so a checkpoint holding a member could not be read back."""
    if isinstance(obj, enum.Enum):
        return obj.value
    if isinstance(obj, dict):
        return {without_enums(k): without_enums(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [without_enums(v) for v in obj]
    if isinstance(obj, tuple):
        return tuple(without_enums(v) for v in obj)
    return obj


def to_tensors(obj):
    """``obj`` with every numpy array a tensor, so that it saves and loads with ``weights_only=True``."""
    if isinstance(obj, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(obj))
    if isinstance(obj, dict):
        return {k: to_tensors(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_tensors(v) for v in obj]
    return obj


def to_arrays(obj):
    """``to_tensors`` undone: every tensor a numpy array."""
    if isinstance(obj, torch.Tensor):
        return obj.numpy()
    if isinstance(obj, dict):
        return {k: to_arrays(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [to_arrays(v) for v in obj]
    return obj


# ------------------------------------------------------------ a trainer's own
TRAINER_STATE_FORMAT = 2
"""Version of the resumable trainer state in checkpoints (1 was a pickle, which ``--resume`` no longer reads)."""


def watcher_state(policy) -> dict:
    """What a resumed run needs of a partner or teacher policy: what it is, and its state."""
    return {"describe": describe_agent(policy.describe()), "state": policy.state_dict()}


def trainer_payload(trainer, device: str) -> dict:
    """The resumable checkpoint of a ``train.trainer.Trainer`` (the layout above): each learner's weights and
    optimizer (its placement's process, if any, first gives its optimizer state back), and everything that decides
    what happens next: env state, last-step inputs, reward sums, recurrent states, generators, partners' and
    teachers' states, torch's RNG. ``device`` names what trained."""
    trainer.placement.sync_optimizers()
    agents = {}
    for i, name in enumerate(trainer.names):
        if i in trainer.learners:
            learner = trainer.learners[i]
            agents[learner.name] = agent_entry(learner.model, learner.optimizer)
        elif i in trainer.partners:
            agents[name] = None
    env = trainer.env
    state = {
        "format": TRAINER_STATE_FORMAT,
        "env_state": {f.name: getattr(env.state, f.name) for f in dataclasses.fields(env.state)},
        "penalty_coef": env.penalty_coef, "last_step": trainer.last.state_dict(), "shaped_sum": trainer.shaped_sum,
        "learners": {lr.name: {"recurrent": None if lr.state is None else list(lr.state),
                               "generator": lr.generator.get_state()} for lr in trainer.learners.values()},
        "partners": {trainer.names[i]: watcher_state(p) for i, p in trainer.partners.items()},
        "teachers": {trainer.names[i]: watcher_state(p) for i, p in trainer.teachers.items()},
        "torch_rng": torch.get_rng_state(),
    }
    return {"config": trainer.config.to_dict(), "env_config": trainer.config.env.to_dict(), "step": trainer.step,
            "iteration": trainer.iteration, "wall_time_s": trainer.wall_time, "device": device,
            "agents": agents, "trainer_state": to_tensors(state)}


def restore_trainer(trainer, path: str | Path) -> None:
    """Continue ``trainer`` from a checkpoint of its run (``trainer_payload``'s): weights, optimizers, env,
    recurrent states, RNGs. The trainer's placement is closed first: its update processes start again from the
    restored optimizers."""
    ckpt = load_checkpoint(path)
    trainer.close()
    if ckpt.get("trainer_state") is None:
        raise ValueError(f"{path} is an exported policy (no trainer state); resume from a run's checkpoints/")
    for learner in trainer.learners.values():
        entry = ckpt["agents"].get(learner.name)
        if entry is None:
            raise ValueError(f"{path} holds no trained {learner.name}, but this run trains one")
        load_weights(learner.model, entry["state_dict"], str(path))
        learner.optimizer.load_state_dict(entry["optimizer"])
    state = ckpt["trainer_state"]
    if not isinstance(state, dict) or state.get("format") != TRAINER_STATE_FORMAT:
        raise ValueError(f"{path} holds a trainer state this colorgrid cannot resume (written by an older version, "
                         f"as a pickle); start a new run with its weights: --set follower.init={path}")
    trainer.obs = trainer.env.load_state(EnvState(**to_arrays(state["env_state"])))
    trainer.env.penalty_coef = float(state["penalty_coef"])
    trainer.last.load_state_dict(to_arrays(state["last_step"]))
    trainer.shaped_sum = to_arrays(state["shaped_sum"])
    for learner in trainer.learners.values():
        saved = state["learners"][learner.name]
        learner.state = None if saved["recurrent"] is None else tuple(t.to(trainer.device) for t in saved["recurrent"])
        learner.generator.set_state(saved["generator"])
    names = trainer.names
    for kind, watchers in (("partner", trainer.partners), ("teacher", trainer.teachers)):
        for i, policy in watchers.items():
            saved = state.get(f"{kind}s", {}).get(names[i])
            if saved is None:
                raise ValueError(f"{path} holds no {names[i]} {kind}, but this run has one; resume with "
                                 f"the run's own settings")
            now = describe_agent(policy.describe())
            try:  # one saved before nested checkpoints were pinned is pinned now, against the files as they are
                before = pin_checkpoints(saved["describe"])
            except OSError as err:
                raise ValueError(f"{path}: the {names[i]} {kind} was {saved['describe']}, whose file cannot be read "
                                 f"now ({err.strerror}: {err.filename}); resume with the same {kind}") from None
            if before != now:
                raise ValueError(f"{path}: the {names[i]} {kind} was {saved['describe']}, now it is {now}; resume "
                                 f"with the same {kind}")
            policy.load_state_dict(saved["state"])
    torch.set_rng_state(state["torch_rng"])
    trainer.step, trainer.iteration = int(ckpt["step"]), int(ckpt["iteration"])
    trainer.wall_time = float(ckpt.get("wall_time_s", 0.0))
