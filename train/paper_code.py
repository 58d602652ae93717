"""The paper's released code (``run_ppo.py``) and this project: its checkpoints, imported.

The paper's conventions (planes ``[RED, BLUE, GREEN, leader, follower]`` indexed ``[x, y]``, its action and
color order) are mapped once, in the core (``colorgrid.paper_format``), where the replay import of its dumps
reads them too. Here the paper model's weights are checked and permuted with that mapping
(``state_dict_from_paper``), so that the imported network computes exactly the paper model's function on our
observations, and written as a checkpoint of this trainer with a model card.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import pickle
import re
import zipfile
from pathlib import Path

import torch

from colorgrid.config import ROLES, EnvConfig
from colorgrid.enums import Role
from colorgrid.paper_format import (
    ACTIONS_FROM_PAPER,
    COLORS_FROM_PAPER,
    PAPER_ACTIONS,
    PAPER_COLORS,
    PAPER_PLANES,
    PAPER_SOURCE,
    PLANES_FROM_PAPER,
    board_from_paper,
)

COMPILED_PREFIX = "_orig_mod."
"""What ``torch.compile`` puts before every key of a compiled model's state dict."""
HIDDEN = 192
"""The paper network's width (projection, feature layers and LSTM)."""


# The paper model's weights ------------------------------------------------------------------------

def paper_shapes(lstm: bool, env: EnvConfig | None = None) -> dict[str, tuple[int, ...]]:
    """The keys and shapes of the state dict of the paper code's ``ActorCritic`` (``use_lstm``: ``lstm``) for
    ``env``'s board (default: the paper's 32x32)."""
    env = env or EnvConfig()
    C, P = len(PAPER_COLORS), len(PAPER_PLANES)
    flat = 64 * (env.height - 6) * (env.width - 6)
    layers = {"conv_network.0": (32, P, 3, 3), "conv_network.2": (64, 32, 3, 3), "conv_network.4": (64, 64, 3, 3),
              "projection_linear.0": (HIDDEN, flat), "feature_linear.0": (HIDDEN, HIDDEN + C),
              "feature_linear.2": (HIDDEN, HIDDEN), "policy_network.0": (64, HIDDEN), "policy_network.2": (64, 64),
              "policy_network.4": (len(PAPER_ACTIONS), 64), "value_network.0": (64, HIDDEN),
              "value_network.2": (64, 64), "value_network.4": (1, 64), "auxiliary_goalinfo_network.0": (64, HIDDEN),
              "auxiliary_goalinfo_network.2": (C, 64)}
    shapes = {}
    for name, shape in layers.items():
        shapes[f"{name}.weight"], shapes[f"{name}.bias"] = shape, shape[:1]
    if lstm:
        shapes.update({"lstm.weight_ih_l0": (4 * HIDDEN, HIDDEN), "lstm.weight_hh_l0": (4 * HIDDEN, HIDDEN),
                       "lstm.bias_ih_l0": (4 * HIDDEN,), "lstm.bias_hh_l0": (4 * HIDDEN,)})
    return shapes


OUR_KEYS = {"conv_network.": "encoder.convs.", "projection_linear.": "encoder.projection.",
            "feature_linear.": "encoder.mlp.", "policy_network.": "policy.", "value_network.": "value.",
            "auxiliary_goalinfo_network.": "aux.", "lstm.": "lstm."}
"""Each paper module's keys' prefix, and ours (``train.nets.ActorCritic`` with ``arch='paper'``,
``goal_fusion='projected'``)."""


def net_config(lstm: bool):
    """Our ``NetConfig`` of the paper code's network (with its LSTM: ``lstm``)."""
    from train.config import NetConfig

    return NetConfig(arch="paper", goal_fusion="projected", lstm=lstm, lstm_size=HIDDEN)


@dataclasses.dataclass(frozen=True)
class PaperWeights:
    """A paper model's state dict, checked, in the paper's layout."""

    state: dict[str, torch.Tensor]
    """Its tensors, keyed as the paper's ``ActorCritic`` names them (without the compile prefix)."""
    lstm: bool
    """Whether it has the LSTM (``use_lstm=True``)."""
    compiled: bool
    """Whether it was saved from a ``torch.compile``d model (every key prefixed ``_orig_mod.``)."""


def check_paper_state_dict(state: object, what: str, role: str) -> PaperWeights:
    """``state`` as ``PaperWeights``; anything else raises one line that says what ``state`` is and what was
    expected."""
    expected = (f"expected the model state dict that the paper's run_ppo.py saves as {role}_iteration=N.pth "
                f"(keys conv_network.*, projection_linear.0.*, feature_linear.*, policy_network.*, value_network.*, "
                f"auxiliary_goalinfo_network.*, and lstm.* with use_lstm)")
    if not isinstance(state, dict):  # a bad file, for the command's one line (a ValueError), not a bug
        raise ValueError(  # noqa: TRY004
            f"{what} holds a {type(state).__name__}, not a state dict; {expected}")
    if {"state", "param_groups"} <= set(state):
        raise ValueError(f"{what} is an optimizer's state (keys 'state', 'param_groups': run_ppo.py writes it as "
                         f"{role}_optimizer_iteration=N.pth), not a model; {expected}")
    if state.get("format") == "colorgrid-ippo":
        raise ValueError(f"{what} is already a ColorGrid checkpoint: load it as it is (colorgrid eval --{role} ...)")
    if not state or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()):
        raise ValueError(f"{what} is not a state dict of tensors (keys {sorted(map(str, state))[:4]}); {expected}")
    compiled = all(k.startswith(COMPILED_PREFIX) for k in state)
    if compiled:
        state = {k[len(COMPILED_PREFIX):]: v for k, v in state.items()}
    lstm = any(k.startswith("lstm.") for k in state)
    shapes = paper_shapes(lstm)
    missing, extra = sorted(set(shapes) - set(state)), sorted(set(state) - set(shapes))
    if missing or extra:
        raise ValueError(f"{what} is not the paper's ActorCritic: missing {missing[:4]}, unexpected {extra[:4]} "
                         f"({len(missing)} missing, {len(extra)} unexpected); {expected}")
    goal_key = "feature_linear.0.weight"
    goal_columns = state[goal_key].shape[-1] - HIDDEN if state[goal_key].dim() == 2 else None
    if goal_columns is not None and goal_columns != len(PAPER_COLORS):
        raise ValueError(f"{what}: {goal_key} takes a {goal_columns}-wide goal input ({tuple(state[goal_key].shape)}); "
                         f"the {role} of the paper's env takes its {len(PAPER_COLORS)}-color goal one-hot (zeros for an "
                         f"asymmetric follower) after the {HIDDEN} projected features: {shapes[goal_key]}")
    wrong = [f"{k} {tuple(state[k].shape)} (expected {shape})" for k, shape in shapes.items()
             if tuple(state[k].shape) != shape]
    if wrong:
        raise ValueError(f"{what} has the paper's keys but not its shapes: {', '.join(wrong[:3])}"
                         f"{f' and {len(wrong) - 3} more' if len(wrong) > 3 else ''}; the paper's network is for its "
                         f"32x32 board, 5 planes, 4 actions and 3 colors")
    return PaperWeights(state, lstm, compiled)


def state_dict_from_paper(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The paper model's weights (checked by ``check_paper_state_dict``) as ours, permuted so that our network
    computes the paper model's function on our observations: the board turns (``board_from_paper``), so every
    conv kernel and the projection's input columns (64 x 26 x 26 features) turn with it; the first conv's input
    channels, the goal columns, the policy's output rows and the auxiliary head's rows are reordered."""
    ours = {}
    for key, value in state.items():
        prefix = next(p for p in OUR_KEYS if key.startswith(p))
        ours[OUR_KEYS[prefix] + key[len(prefix):]] = value.detach().to(torch.float32).clone()
    for i in (0, 2, 4):  # a cross-correlation of a turned board with turned kernels is the turned result
        ours[f"encoder.convs.{i}.weight"] = board_from_paper(ours[f"encoder.convs.{i}.weight"])
    ours["encoder.convs.0.weight"] = ours["encoder.convs.0.weight"][:, PLANES_FROM_PAPER]
    projection = ours["encoder.projection.0.weight"]
    side = round((projection.shape[1] / 64) ** 0.5)
    ours["encoder.projection.0.weight"] = board_from_paper(projection.reshape(-1, 64, side, side)).reshape(
        projection.shape[0], -1)
    goal = ours["encoder.mlp.0.weight"]
    ours["encoder.mlp.0.weight"] = torch.cat([goal[:, :HIDDEN], goal[:, HIDDEN:][:, COLORS_FROM_PAPER]], dim=1)
    for key in ("policy.4.weight", "policy.4.bias"):
        ours[key] = ours[key][ACTIONS_FROM_PAPER]
    for key in ("aux.2.weight", "aux.2.bias"):
        ours[key] = ours[key][COLORS_FROM_PAPER]
    return {k: v.contiguous() for k, v in ours.items()}


def read_paper_state_dict(path: str | Path, role: str) -> PaperWeights:
    """A paper checkpoint file, checked (``check_paper_state_dict``); a file torch cannot read safely raises
    one line."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 (torch raises many types for a file it cannot read)
        if path.stat().st_size == 0:
            why = "the file is empty"
        elif not zipfile.is_zipfile(path):
            why = "it is not a file written by torch.save (a compressed .gz? gunzip it first)"
        elif isinstance(err, pickle.UnpicklingError):
            why = "it holds objects other than tensors and plain containers (a whole pickled model?)"
        else:
            why = f"{type(err).__name__}: {str(err).strip().splitlines()[0][:160] if str(err).strip() else ''}"
        raise ValueError(f"{path} is not a readable paper checkpoint: {why}") from None
    return check_paper_state_dict(state, str(path), role)


def import_paper_checkpoint(src: str | Path, role: str, out: str | Path, asymmetric: bool) -> Path:
    """Turn a state dict saved by the paper's ``run_ppo.py`` into a ColorGrid checkpoint at ``out`` that plays
    ``role`` (``leader`` or ``follower``) in the 1:1 team, with a model card (``out`` with ``.md``) beside it.
    ``asymmetric``: the env it was trained in (the follower saw no goal), recorded in the checkpoint's env."""
    from train.checkpoint import load_weights, save_checkpoint
    from train.config import AgentConfig, TrainConfig
    from train.nets import ActorCritic

    if role not in ROLES:
        raise ValueError(f"--role {role!r}: the paper's team has a {' and a '.join(ROLES)}; choose one")
    src, out = Path(src), Path(out)
    if out.suffix != ".pt":
        raise ValueError(f"--out {out}: a checkpoint path ending in .pt (where every command loads it)")
    weights = read_paper_state_dict(src, role)
    env = EnvConfig(asymmetric=asymmetric)
    net = net_config(weights.lstm)
    agent = env.index(role)
    with torch.random.fork_rng(devices=[]):  # every weight is overwritten
        model = ActorCritic(net, env, agent)
    load_weights(model, state_dict_from_paper(weights.state), str(src))
    partner = {"leader": "idle", "follower": "astar"}[role]
    agents = {name: AgentConfig(net=net) if name == role else AgentConfig(policy=partner) for name in ROLES}
    config = TrainConfig(env=env, **agents)
    iteration = re.search(r"iteration=(\d+)", src.name)
    source = {"file": src.name, "sha256": hashlib.sha256(src.read_bytes()).hexdigest(), "code": PAPER_SOURCE,
              "role": role, "lstm": weights.lstm, "compiled": weights.compiled,
              "iteration": int(iteration.group(1)) if iteration else None}
    entry = {"net": dataclasses.asdict(net), "agent_index": agent,
             "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}, "optimizer": None}
    path = save_checkpoint(out, {"config": config.to_dict(), "env_config": env.to_dict(), "step": 0,
                                 "iteration": source["iteration"], "agents": {name: entry if name == role else None
                                                                              for name in ROLES},
                                 "trainer_state": None, "imported_from": source})
    out.with_suffix(".md").write_text(model_card(path, source, net, env))
    return path


def model_card(path: Path, source: dict, net, env: EnvConfig) -> str:
    """The card of an imported checkpoint: where it came from, what was mapped, how to run it."""
    role = source["role"]
    iteration = f", iteration {source['iteration']} of its run" if source["iteration"] is not None else ""
    lines = [
        f"# Model card: `{path.name}` (the {role}, imported from the paper's code)",
        "",
        (f"- **Source**: `{source['file']}` (sha256 `{source['sha256']}`), a state dict saved by the paper's "
         f"{source['code']}{iteration}; "
         f"{'saved after torch.compile (keys prefixed _orig_mod.); ' if source['compiled'] else ''}"
         f"{'with' if source['lstm'] else 'without'} its LSTM."),
        ("- **Imported with**: `colorgrid checkpoint import-paper "
         f"{source['file']} --role {role} --out {path.name} --{'asymmetric' if env.asymmetric else 'symmetric'}`"),
        "- **Training**: not recorded in the file (steps, PPO settings, partner); this checkpoint's step is 0.",
        (f"- **Network**: {json.dumps(dataclasses.asdict(net))}: the paper code's network exactly, the goal one-hot "
         "joined after the 43264->192 projection."),
        ("- **Mapped** (colorgrid/paper_format.py): planes RED, BLUE, GREEN -> red, green, blue; boards indexed [x, y] "
         "(y up) -> [row, col] (row 0 at the top); actions UP (y+1), DOWN, LEFT, RIGHT -> up, down, left, right; "
         "goal one-hot and auxiliary head in our color order. The weights are permuted so that the network computes "
         "the paper model's function on this project's observations."),
        (f"- **Environment recorded**: {json.dumps(env.to_dict())}. The paper's env differs from this one in a few "
         "rules (docs/PAPER_CODE.md)."),
        "",
        "Run it: " + (f"`colorgrid eval --leader {path.name} --follower bayes`" if role == Role.LEADER else
                      f"`colorgrid eval --leader astar --follower {path.name}`") +
        " (any command that takes a checkpoint .pt takes it).",
        "",
        "Play with it in the browser: " + (
            f"`colorgrid play --leaders {path.name}`, then the team \"two leaders, one AI follower\" and \"The other "
            f"leader: {path.name} (imported from the paper's code)\": it leads beside you as the AI leader of a 2:1 "
            "game, which it sees as the 1:1 game it was trained in: itself and the follower, you not in its view"
            if role == Role.LEADER else
            f"`colorgrid play --follower {path.name}`: it assists you as your AI partner in the 1:1 team, the one it "
            "was trained in") + "; see docs/PAPER_CODE.md, \"Play with it in the browser\".",
    ]
    return "\n".join(lines) + "\n"
