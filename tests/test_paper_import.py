"""Checkpoints of the paper's own code (``run_ppo.py``), imported: the same function on our observations.

The fixture (``tests/data/paper/``, made by running the paper's released code; see
``/work/shared/paper_artifacts/README.md`` where it came from) is a leader's state dict, one 128-step episode it
played in ``run_ppo.py``'s dump format, and the paper model's outputs on each of its frames.
"""

import gzip
import io

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from colorgrid import paper_format
from colorgrid.config import AGENTS, LEADER, EnvConfig
from colorgrid.env import move_table
from colorgrid.policies.base import AgentInput
from colorgrid_apps.cli import main
from tests.conftest import ROOT
from train import paper_code
from train.policy import load_policy

DATA = ROOT / "tests" / "data" / "paper"
TOLERANCE = 1e-4


def gunzipped(name: str) -> bytes:
    return gzip.decompress((DATA / name).read_bytes())


@pytest.fixture(scope="module")
def paper_state() -> dict[str, torch.Tensor]:
    return torch.load(io.BytesIO(gunzipped("paper_leader.pth.gz")), map_location="cpu", weights_only=True)


@pytest.fixture(scope="module")
def episode() -> dict[str, np.ndarray]:
    """The dump in the paper's layout: ``planes [128, 5, 32, 32]`` (x, y), ``goal [128, 3]``, and the outputs."""
    expected = np.load(DATA / "expected_outputs.npz")
    return {"planes": np.load(io.BytesIO(gunzipped("trajectory_iteration=0_env=0.npy.gz"))),
            "goal": np.load(DATA / "goal_info_iteration=0_env=0.npy"), **{k: expected[k] for k in expected.files}}


@pytest.fixture(scope="module")
def imported(tmp_path_factory, paper_state) -> dict:
    """The leader imported through the command, as a user would: ``{"pth", "pt"}`` paths."""
    folder = tmp_path_factory.mktemp("paper")
    pth = folder / "leader_iteration=0.pth"
    torch.save(paper_state, pth)
    out = folder / "paper_leader.pt"
    assert main(["checkpoint", "import-paper", str(pth), "--role", "leader", "--out", str(out)]) == 0
    return {"pth": pth, "pt": out}


def paper_forward(state: dict[str, torch.Tensor], planes: torch.Tensor, goal: torch.Tensor):
    """The paper code's ``ActorCritic.forward`` in the paper's own layout, written out from its layers:
    ``planes [N, 5, X, Y]``, ``goal [N, 3]``. With ``lstm.*`` weights, the N frames are one episode: the LSTM
    steps through them one at a time from a zero state, as ``run_ppo.py`` calls it. Checked against the
    paper's own outputs below."""
    x = planes.float()
    for i in (0, 2, 4):
        x = F.leaky_relu(F.conv2d(x, state[f"conv_network.{i}.weight"], state[f"conv_network.{i}.bias"]))
    x = torch.tanh(F.linear(x.flatten(1), state["projection_linear.0.weight"], state["projection_linear.0.bias"]))
    x = torch.cat([x, goal], dim=1)
    for i in (0, 2):
        x = torch.tanh(F.linear(x, state[f"feature_linear.{i}.weight"], state[f"feature_linear.{i}.bias"]))
    if "lstm.weight_ih_l0" in state:
        lstm = torch.nn.LSTM(192, 192, batch_first=True)
        lstm.load_state_dict({k[len("lstm."):]: v for k, v in state.items() if k.startswith("lstm.")})
        recurrent, steps = (torch.zeros(1, 1, 192), torch.zeros(1, 1, 192)), []
        for features in x:
            out, recurrent = lstm(features.reshape(1, 1, -1), recurrent)
            steps.append(out[:, -1])
        x = torch.cat(steps)

    def head(name, n):
        h = x
        for i in range(n):
            h = F.linear(h, state[f"{name}.{2 * i}.weight"], state[f"{name}.{2 * i}.bias"])
            h = torch.tanh(h) if i < n - 1 else h
        return h

    return head("policy_network", 3), head("value_network", 3)[:, 0], head("auxiliary_goalinfo_network", 2)


def our_outputs(model, planes: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, ...]:
    """Our network on a sequence of one env: ``planes [T, 5, H, W]`` (ours), ``goal [T, 3]`` (ours)."""
    T = len(planes)
    starts = torch.zeros(T, 1, dtype=torch.bool)
    starts[0] = True
    with torch.no_grad():
        view = model.prepare(torch.from_numpy(planes)[:, None], torch.zeros(T, 1, 2, dtype=torch.long))
        logits, value, aux, _ = model(view, torch.from_numpy(goal.astype(np.float32))[:, None],
                                      torch.zeros(T, 1, 0), starts, model.initial_state(1))
    return logits[:, 0].numpy(), value[:, 0].numpy(), aux[:, 0].numpy()


def test_the_reference_forward_is_the_paper_models(paper_state, episode):
    """The hand-written forward that the LSTM test leans on gives the paper's own outputs."""
    with torch.no_grad():
        logits, value, aux = paper_forward(paper_state, torch.from_numpy(episode["planes"]),
                                              torch.from_numpy(episode["goal"]).float())
    assert np.abs(logits.numpy() - episode["logits"]).max() < TOLERANCE
    assert np.abs(value.numpy() - episode["value"]).max() < TOLERANCE
    assert np.abs(aux.numpy() - episode["aux"]).max() < TOLERANCE


def test_imported_leader_gives_the_paper_models_outputs_on_our_observations(imported, episode):
    policy = load_policy(imported["pt"], "leader")
    planes = paper_format.observation_from_paper(episode["planes"])
    goal = paper_format.colors_from_paper(episode["goal"])
    logits, value, aux = our_outputs(policy.model, planes, goal)
    want_logits = paper_format.action_values_from_paper(episode["logits"])
    want_aux = paper_format.colors_from_paper(episode["aux"])
    errors = {"logits": np.abs(logits - want_logits).max(), "value": np.abs(value - episode["value"]).max(),
              "aux": np.abs(aux - want_aux).max()}
    assert max(errors.values()) < TOLERANCE, errors
    # the outputs vary with the board, so matching them tests the mapping (a wrong turn or order would not)
    assert np.ptp(want_logits, axis=0).min() > 0.5 and np.ptp(want_aux, axis=0).min() > 0.5

    # the policy as every command runs it (step_tensors, greedy acting): the paper's most likely move, in our
    # action order, and its goal belief in our color order
    T = len(planes)
    policy.temperature = 0.0
    policy.reset(EnvConfig(asymmetric=False), T, LEADER)
    inp = AgentInput(observation=planes, goal_info=goal.astype(np.float32), episode_start=np.ones(T, bool),
                     prev_reward=np.zeros(T, np.float32), prev_picked_color=np.full((T, 2), -1),
                     prev_actions=np.full((T, 2), -1))
    out = policy.act(inp)
    np.testing.assert_array_equal(out.actions, want_logits.argmax(axis=1))
    np.testing.assert_allclose(out.goal_probs, torch.softmax(torch.from_numpy(want_aux), 1).numpy(), atol=1e-5)


def test_the_paper_actions_mapped_move_the_leader_through_its_positions(episode):
    config = EnvConfig()
    planes = paper_format.observation_from_paper(episode["planes"])
    cells = paper_format.cells_from_paper(episode["leader_xy"], config.height)  # [T, 2] (row, col)
    leader_plane = planes[:, config.num_colors + LEADER].reshape(len(planes), -1)
    flat = cells[:, 0] * config.width + cells[:, 1]
    assert (leader_plane[np.arange(len(planes)), flat] == 1).all() and (leader_plane.sum(axis=1) == 1).all()
    actions = paper_format.actions_from_paper(episode["action"])
    moved = move_table(config)[LEADER][flat[:-1], actions[:-1]]  # our rules' moves (walls included)
    np.testing.assert_array_equal(moved, flat[1:])
    assert len(set(flat.tolist())) > 10  # the leader went places


def test_compiled_prefix_imports_the_same(tmp_path, paper_state, imported):
    pth = tmp_path / "leader_iteration=0.pth"
    torch.save({paper_code.COMPILED_PREFIX + k: v for k, v in paper_state.items()}, pth)
    out = tmp_path / "compiled.pt"
    assert main(["checkpoint", "import-paper", str(pth), "--role", "leader", "--out", str(out), "--symmetric"]) == 0
    ours, plain = (load_policy(p, "leader").model.state_dict() for p in (out, imported["pt"]))
    assert ours.keys() == plain.keys() and all(torch.equal(ours[k], plain[k]) for k in ours)
    card = (tmp_path / "compiled.md").read_text()
    assert "_orig_mod." in card and "`colorgrid play --leaders compiled.pt`" in card  # the AI leader of a 2:1 game


def test_lstm_follower_imports_with_its_recurrent_core(tmp_path, paper_state, episode):
    """The paper's asymmetric follower with its LSTM (after feature_linear; heads read its output; zero state at
    an episode's start) is our recurrent network: the same outputs over the whole episode."""
    generator = torch.Generator().manual_seed(0)
    lstm = {f"lstm.{k}": torch.randn(v.shape, generator=generator) * 0.2
            for k, v in torch.nn.LSTM(192, 192).state_dict().items()}
    state = {**paper_state, **lstm}
    pth = tmp_path / "follower_iteration=7.pth"
    torch.save(state, pth)
    out = tmp_path / "follower.pt"
    assert main(["checkpoint", "import-paper", str(pth), "--role", "follower", "--asymmetric", "--out", str(out)]) == 0
    model = load_policy(out, "follower").model
    assert model.lstm is not None and model.agents == (AGENTS.index("follower"),)
    zeros = np.zeros((len(episode["goal"]), 3), np.float32)  # the asymmetric follower's goal input
    logits, value, aux = our_outputs(model, paper_format.observation_from_paper(episode["planes"]), zeros)
    with torch.no_grad():
        want_logits, want_value, want_aux = (t.numpy() for t in paper_forward(
            state, torch.from_numpy(episode["planes"]), torch.from_numpy(zeros)))
    assert np.abs(logits - paper_format.action_values_from_paper(want_logits)).max() < TOLERANCE
    assert np.abs(value - want_value).max() < TOLERANCE
    assert np.abs(aux - paper_format.colors_from_paper(want_aux)).max() < TOLERANCE
    card = out.with_suffix(".md").read_text()
    assert "iteration 7" in card and "`colorgrid play --follower follower.pt`" in card


@pytest.mark.parametrize("content, says", [
    ({"state": {}, "param_groups": [{"lr": 1e-4, "params": [0, 1]}]}, "is an optimizer's state"),
    ("wrong goal", "takes a 4-wide goal input"),
    ("wrong actions", "has the paper's keys but not its shapes: policy_network.4.weight (5, 64)"),
    ({"weight": torch.zeros(3)}, "is not the paper's ActorCritic: missing"),
])
def test_a_file_that_is_not_a_paper_model_gets_one_line(tmp_path, capsys, paper_state, content, says):
    if content == "wrong goal":
        content = {**paper_state, "feature_linear.0.weight": torch.zeros(192, 196)}
    elif content == "wrong actions":
        content = {**paper_state, "policy_network.4.weight": torch.zeros(5, 64), "policy_network.4.bias": torch.zeros(5)}
    pth = tmp_path / "leader_iteration=1.pth"
    torch.save(content, pth)
    out = tmp_path / "out.pt"
    assert main(["checkpoint", "import-paper", str(pth), "--role", "leader", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("colorgrid checkpoint import-paper: error: ") and says in err, err
    assert not out.exists()


def test_imported_leader_plays_colorgrid_eval(imported, capsys):
    assert main(["eval", "--leader", str(imported["pt"]), "--follower", "idle", "--episodes", "2",
                 "--set", "horizon=12", "--set", "asymmetric=false"]) == 0
    report = capsys.readouterr().out
    assert "paper_leader" in report and "leader goal pickups" in report
