"""Can a policy's image encoder read, from an AssemblingKits recording's cameras, where the slot is?

    python studies/assembling_kits_pixels/perception_probe.py DATASET [DATASET ...] [--encoders act,diffusion]
        [--shifts 0.05,0]
        [--steps 2000] [--batch 32] [--lr 3e-4] [--checkpoints 500,1000,2000] [--eval-frames 1000] [--out report.json]
        [--targets goal,yaw,shape,turn,shape_yaw,grip[,hand]] [--with-state] [--hold-out episodes|kits]
        [--train-episodes N]
        [--save-policy DIR --policy-config policies/act_assembling_kits_rgb_cpu.json]

An image policy that fails to carry the shape to its slot either cannot see where the slot is or does not learn to
use it. This separates the two. For every dataset x encoder x shift it trains the encoder, built by lerobot's own
classes as the policy builds it, from scratch, with a small head that regresses from the recording's cameras (every
camera through the one shared encoder, as both policies share it) what the expert's transport depends on: the
slot's position (`goal_xy`), its yaw folded by the shape's symmetry (`goal_yaw_sym`), the loose shape's
position, the turn the shape still needs to fit its slot (`obj_to_goal_yaw`, folded likewise: what the hand's
turn in the transport depends on), and the two yaws that turn is made of: the loose shape's own (`obj_yaw_sym`) and
the shape's yaw in the hand (its yaw less the hand's, `tcp_yaw`, folded by its symmetry: what a picture can tell
and the insertion needs; the state's `tcp_to_obj_yaw` is folded by a half turn, which no picture of a square
resolves). Nothing but the images
goes in, unless `--with-state` adds the arm's own state (joints and gripper, as the policy reads it) beside the
encoder's features: the hand's yaw is in the joints, so the turn needs the images to give only the shape's yaw in
the hand and the slot's. `--targets` trains on a subset. It then scores the held-out episodes (the last 10% of the
recording), and as many of its training frames (`seen`: what it fits, against what it reads of new episodes).
`--hold-out kits` also keeps out of training every episode whose kit a held-out episode has (a kit recurs in about
three episodes of a recording, so otherwise the slot can be recognised from the kit's layout rather than measured);
`--train-episodes N` trains on the first N of the training episodes only, the held-out ones unchanged (how a
figure grows with the demonstrations):

- slot: the predicted slot position's error (mm, median / p90), and how often the slot nearest to the prediction is
  the right one of the kit's five (`right slot`). A kit has empty pockets besides the target's; `chance` is what
  picking one of its empty pockets at random gets, `mean` what predicting the training set's mean position gets.
- yaw: the slot's yaw error (degrees, median) and the share within the success test's 4 degrees, for the shapes
  whose yaw matters (not the disc or ring).
- shape: the loose shape's position error (mm, median).
- turn: the error of the turn still needed (degrees, median), the share within 4 degrees, and the median over the
  frames where more than 4 degrees are still to turn (`turning`: before the expert has turned the shape), and over
  those of them where the shape is up in the hand (`carried`: the turn the policy makes in the transport), and of
  those where it is within 2 cm of its slot (`over the slot`: where an expert with `turn_over_slot` makes the turn).
- shape_yaw, grip: the loose shape's yaw error and the error of its yaw in the hand (degrees, median), each with the
  share within 4 degrees; the yaw in the hand's also over the `carried` frames (up in the hand, still to turn).
- hand (trained only when `--targets` names it): the error of the hand's yaw with the shape seated, the slot's yaw
  less the yaw in the hand (folded likewise), what an absolute action (`pd_ee_pose`) asks for where a delta one
  asks for the turn; with the share within 4 degrees, and over the `carried` frames.

Encoders: `act` (ACT's backbone: ResNet-18 with frozen batch norm, its layer-4 map, then a 1x1 projection, as
ACT's tokens are made; a map a side 1/32 of the image's: ACT's `replace_final_stride_with_dilation` raises for a
ResNet-18, whose blocks torchvision builds without dilation), `diffusion` (Diffusion's encoder: ResNet-18 with
group norm and its spatial-softmax keypoints). The head is
the same small MLP for all. `--shifts` are the training images' random shifts (the share of the image a side, as
the image configs' `RandomAffine` translate; 0 for none). Figures come from one training seed each (1000); how far
they move between seeds is not measured.

`--save-policy DIR` (one dataset, the `act` encoder, one shift) writes an ACT policy built as `--policy-config`'s
`lerobot-train` builds it on that recording, its image backbone the trained encoder's, with its processors: stock
`lerobot-train --config_path=<config> --policy.path=DIR` then trains the policy from it, a two-stage training
whose first stage learns the slot from a direct target. Exit status: 2 for a bad argument.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from kitbench.errors import KitbenchError  # noqa: E402

ENCODERS = ("act", "diffusion")
TASK = "AssemblingKits-v1"
IMAGES = "observation.images."
ENVIRONMENT_STATE = "observation.environment_state"
# the regression targets, by their names in the environment state
TARGETS = {
    "goal": ("goal_xy.0", "goal_xy.1"),
    "yaw": ("goal_yaw_sym.0", "goal_yaw_sym.1"),
    "shape": ("obj_pose.x", "obj_pose.y"),
    "turn": ("obj_to_goal_yaw.0", "obj_to_goal_yaw.1"),
    "shape_yaw": ("obj_yaw_sym.0", "obj_yaw_sym.1"),
    "grip": ("obj_yaw_sym.0", "obj_yaw_sym.1"),  # less the hand's yaw (HAND_YAW): `in_hand_yaw`
    "hand": ("goal_yaw_sym.0", "goal_yaw_sym.1"),  # less the yaw in the hand: `hand_over_slot`
}
# trained unless --targets names others: `hand` came later, and training it beside the rest moves their figures
DEFAULT_TARGETS = ("goal", "yaw", "shape", "turn", "shape_yaw", "grip")
HAND_YAW = ("tcp_yaw.0", "tcp_yaw.1")
SHAPE_Z = "obj_pose.z"
LIFTED = 0.01  # m above where its episode's shape started: the shape is in the hand (`carried` figures)
OVER_SLOT = 0.02  # m from its slot, horizontally: a carried shape is over it (`over the slot` figure)
# the yaw targets and the symmetry each is folded by (None: the shape's own)
YAW_TARGETS = {"yaw": None, "turn": None, "shape_yaw": None, "grip": None, "hand": None}
STATE = "observation.state"
COLUMNS = {name: slice(2 * i, 2 * i + 2) for i, name in enumerate(TARGETS)}  # each target's columns of `targets`
HELD_OUT = 0.1  # the share of the recording's episodes, its last ones, scored and never trained on
HOLD_OUT = ("episodes", "kits")  # what the held-out episodes keep from training: themselves, or their kits too
PROJECTED = 32  # channels of ACT's feature map kept a cell (ACT projects to its model width; the head stays small)
HIDDEN = 256
YAW_TOLERANCE = 4.0  # degrees: the task's rot_correct


@dataclass(frozen=True)
class Recording:
    """What the probe reads of one AssemblingKits recording: its frames' targets and episodes, and per episode
    its kit's slots."""

    root: Path
    cameras: tuple[str, ...]
    image_shape: tuple[int, int, int]  # C, H, W
    camera_size: str
    camera_view: str | None
    targets: np.ndarray  # frames x 14: goal x y, then cos sin or x y of each of TARGETS in its order
    episode_of: np.ndarray  # frame -> episode index
    slots: dict[int, np.ndarray]  # episode index -> its kit's slot positions (5 x 2)
    target_slot: dict[int, int]  # episode index -> the index of the slot its shape goes into
    empty: dict[int, int]  # episode index -> empty pockets of its kit (the target's included)
    symmetry: dict[int, float]  # episode index -> its shape's rotational symmetry (rad; 0: any yaw fits)
    repo_id: str = f"kitbench/{TASK}"
    state: np.ndarray | None = None  # frames x the arm's state (joints, gripper): what --with-state adds
    kit: dict[int, int] = field(default_factory=dict)  # episode index -> its kit (the episode file's kit_episode)
    lifted: np.ndarray | None = None  # frame -> the shape is up in the hand (LIFTED above its episode's start)
    shape_of: dict[int, int] = field(default_factory=dict)  # episode index -> its shape's id


def lifted_frames(z: np.ndarray, episode_of: np.ndarray) -> np.ndarray:
    """Per frame whether the shape is more than LIFTED above its height in its episode's first frame."""
    _, first, episode = np.unique(episode_of, return_index=True, return_inverse=True)
    return z > z[first][episode] + LIFTED


def _angle(cos_sin: np.ndarray) -> np.ndarray:
    return np.arctan2(cos_sin[:, 1], cos_sin[:, 0])


def _folded(angle: np.ndarray, order: np.ndarray) -> np.ndarray:
    """[cos, sin] of an angle already folded by the symmetry's order; [1, 0] where the order is 0 (a disc or ring,
    which any yaw fits)."""
    folded = np.stack([np.cos(angle), np.sin(angle)], axis=1).astype(np.float32)
    folded[order == 0] = [1.0, 0.0]
    return folded


def in_hand_yaw(shape_yaw_sym: np.ndarray, hand_yaw: np.ndarray, order: np.ndarray) -> np.ndarray:
    """[cos, sin] of `order` x (the shape's yaw less the hand's), per frame: the shape's yaw in the hand folded by
    its symmetry, from its world yaw already so folded ([cos, sin] of order x yaw) and the hand's ([cos, sin]).
    [1, 0] where the order is 0 (a disc or ring, which any yaw fits)."""
    return _folded(_angle(shape_yaw_sym) - order * _angle(hand_yaw), order)


def hand_over_slot(slot_yaw_sym: np.ndarray, in_hand: np.ndarray, order: np.ndarray) -> np.ndarray:
    """[cos, sin] of `order` x the hand's yaw with the shape seated, per frame: the slot's yaw less the shape's yaw in
    the hand, both given folded by the shape's symmetry. What an absolute action (`pd_ee_pose`) asks of the hand,
    where a delta one asks for the turn still to make (the same less the hand's yaw now). [1, 0] where the order
    is 0."""
    return _folded(_angle(slot_yaw_sym) - _angle(in_hand), order)


def read_recording(root: Path) -> Recording:
    """One recording's targets and kits; a folder that is not an AssemblingKits recording with cameras is one
    line."""
    from kitbench.kits import shape_geometry
    from kitbench.metadata import RecordingInfo, read_episode_file
    from kitbench.tasks.assembling_kits import ROBOT_VARIANTS, KitVariant, _load
    from kitbench.training.columns import column_array

    recording = RecordingInfo.read(root)
    if recording is None:
        raise KitbenchError(f"{root} is not a kitbench recording (no meta/kitbench_recording.json)")
    if recording.task != TASK:
        raise KitbenchError(f"{root} records {recording.task}; the probe reads {TASK} recordings only")
    info = json.loads((root / "meta" / "info.json").read_text())
    features = info["features"]
    cameras = tuple(sorted(k for k in features if k.startswith(IMAGES)))
    if not cameras:
        raise KitbenchError(f"{root} has no camera images (obs_mode {recording.obs_mode}); record with rgb")
    h, w, c = features[cameras[0]]["shape"]
    names = features[ENVIRONMENT_STATE]["names"]
    columns = [names.index(n) for group in TARGETS.values() for n in group]

    import pyarrow.parquet as pq

    table = pq.read_table(
        sorted((root / "data").rglob("*.parquet")), columns=[ENVIRONMENT_STATE, STATE, "episode_index", "index"]
    )
    order = np.argsort(column_array(table.column("index")), kind="stable")  # row i is the dataset's frame i
    state = column_array(table.column(ENVIRONMENT_STATE))[order].astype(np.float32)
    arm = column_array(table.column(STATE))[order].astype(np.float32)
    episode_of = column_array(table.column("episode_index"))[order].astype(np.int64)
    kits = _load(None, ROBOT_VARIANTS.get(recording.robot or "", KitVariant()).scale)
    slots, target_slot, empty, symmetry, kit_of, shape_of = {}, {}, {}, {}, {}, {}
    for line in read_episode_file(root):
        i = int(line.episode_index)
        kit_of[i] = int(line.config["kit_episode"])
        kit = kits[kit_of[i]]
        slots[i] = np.array([s.pos for s in kit.slots], dtype=np.float64)
        target_slot[i] = int(kit.obj_to_place)
        empty[i] = len(kit.slots) - len(kit.obj_in_place)
        symmetry[i] = float(shape_geometry(kit.target_slot.shape_id, kits.board.scale).symmetry)
        shape_of[i] = int(kit.target_slot.shape_id)
    targets = state[:, columns]
    # each frame's symmetry order (0 for a disc or ring), computed once an episode
    episodes, frame_episode = np.unique(episode_of, return_inverse=True)
    fold = np.array([2 * math.pi / symmetry[int(e)] if symmetry[int(e)] > 0 else 0.0 for e in episodes])
    hand = state[:, [names.index(n) for n in HAND_YAW]]
    targets[:, COLUMNS["grip"]] = in_hand_yaw(targets[:, COLUMNS["grip"]], hand, fold[frame_episode])
    targets[:, COLUMNS["hand"]] = hand_over_slot(
        targets[:, COLUMNS["yaw"]], targets[:, COLUMNS["grip"]], fold[frame_episode]
    )
    lifted = lifted_frames(state[:, names.index(SHAPE_Z)], episode_of)
    return Recording(
        root=root,
        cameras=cameras,
        image_shape=(c, h, w),
        camera_size=f"{w}x{h}",
        camera_view=recording.camera_view,
        targets=targets,
        episode_of=episode_of,
        slots=slots,
        target_slot=target_slot,
        empty=empty,
        symmetry=symmetry,
        repo_id=recording.repo_id or f"kitbench/{TASK}",
        state=arm,
        kit=kit_of,
        lifted=lifted,
        shape_of=shape_of,
    )


def build_encoder(kind: str, image_shape: tuple[int, int, int]):
    """(module, features per camera): the image encoder of lerobot's ACT or Diffusion, built by their own classes
    from scratch (no pretrained weights: none can be downloaded here, and the shipped configs use none)."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature

    inputs = {
        "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(8,)),
        IMAGES + "probe": PolicyFeature(type=FeatureType.VISUAL, shape=image_shape),
    }
    outputs = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(7,))}
    if kind == "diffusion":
        from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
        from lerobot.policies.diffusion.modeling_diffusion import DiffusionRgbEncoder

        config = DiffusionConfig(
            input_features=inputs, output_features=outputs, crop_shape=None, pretrained_backbone_weights=None
        )
        encoder = DiffusionRgbEncoder(config)
        return encoder, encoder.feature_dim
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACT

    config = ACTConfig(
        input_features=inputs,
        output_features=outputs,
        pretrained_backbone_weights=None,
    )
    backbone = ACT(config).backbone

    class ActMap(torch.nn.Module):
        """ACT's layer-4 feature map, projected a cell and flattened (the tokens' content and their places)."""

        def __init__(self):
            super().__init__()
            self.backbone = backbone
            self.project = torch.nn.Conv2d(512, PROJECTED, kernel_size=1)

        def forward(self, x):
            return self.project(self.backbone(x)["feature_map"]).flatten(1)

    module = ActMap()
    with torch.no_grad():
        size = module(torch.zeros(1, *image_shape)).shape[1]
    return module, size


def _image_stats(root: Path, cameras: tuple[str, ...]):
    """Per camera the dataset's per-channel mean and std (the policies' MEAN_STD image normalisation)."""
    stats = json.loads((root / "meta" / "stats.json").read_text())
    return {
        cam: (
            np.array(stats[cam]["mean"], dtype=np.float32).reshape(3, 1, 1),
            np.array(stats[cam]["std"], dtype=np.float32).reshape(3, 1, 1),
        )
        for cam in cameras
    }


def _folded_yaw_error(pred: np.ndarray, true: np.ndarray, symmetry: float) -> float:
    """Degrees between two yaws given folded by the shape's symmetry ([cos, sin] of k * yaw, k = 2 pi / symmetry),
    as the task's success test measures it."""
    from kitbench.tasks.assembling_kits import yaw_error

    k = 2 * math.pi / symmetry
    return math.degrees(yaw_error(math.atan2(pred[1], pred[0]) / k, math.atan2(true[1], true[0]) / k, symmetry))


def score(recording: Recording, frames: np.ndarray, predicted: np.ndarray) -> dict:
    """The held-out figures of predictions (frames x 14, in the targets' units) of `frames`."""
    true = recording.targets[frames]
    goal, shape, turn_cols = COLUMNS["goal"], COLUMNS["shape"], COLUMNS["turn"]
    goal_err = np.linalg.norm(predicted[:, goal] - true[:, goal], axis=1) * 1000
    shape_err = np.linalg.norm(predicted[:, shape] - true[:, shape], axis=1) * 1000
    right: list[bool] = []
    errors: dict[str, list[float]] = {name: [] for name in YAW_TARGETS}
    turning: list[float] = []
    carried: dict[str, list[float]] = {"turn": [], "grip": [], "hand": []}  # in the hand, the turn still to make
    over_slot: list[float] = []  # the turn still to make, carried and over the slot
    apart = np.linalg.norm(true[:, shape] - true[:, goal], axis=1)
    for row, frame in enumerate(frames):
        episode = int(recording.episode_of[frame])
        nearest = int(np.argmin(np.linalg.norm(recording.slots[episode] - predicted[row, goal], axis=1)))
        right.append(nearest == recording.target_slot[episode])
        symmetry = recording.symmetry[episode]
        if symmetry > 0:  # a shape any yaw fits has no yaw figure, in the hand or out of it
            for name, folded_by in YAW_TARGETS.items():
                cols = COLUMNS[name]
                errors[name].append(_folded_yaw_error(predicted[row, cols], true[row, cols], folded_by or symmetry))
            if _folded_yaw_error(true[row, turn_cols], np.array([1.0, 0.0]), symmetry) > YAW_TOLERANCE:
                turning.append(errors["turn"][-1])
                if recording.lifted is not None and recording.lifted[frame]:
                    carried["turn"].append(errors["turn"][-1])
                    carried["grip"].append(errors["grip"][-1])
                    carried["hand"].append(errors["hand"][-1])
                    if apart[row] < OVER_SLOT:
                        over_slot.append(errors["turn"][-1])
    yaws = {name: np.array(v) if v else np.array([np.nan]) for name, v in errors.items()}
    still = np.array(turning) if turning else np.array([np.nan])
    figures = {
        "goal_mm": [float(np.median(goal_err)), float(np.percentile(goal_err, 90))],
        "right_slot": float(np.mean(right)),
        "shape_mm": float(np.median(shape_err)),
        "turning_deg": float(np.median(still)),
    }
    for name, values in carried.items():
        figures[f"carried_{name}_deg"] = float(np.median(values)) if values else math.nan
    figures["over_slot_turn_deg"] = float(np.median(over_slot)) if over_slot else math.nan
    figures["over_slot_frames"] = len(over_slot)
    for name, values in yaws.items():
        figures[f"{name}_deg"] = float(np.median(values))
        figures[f"{name}_within_4deg"] = float(np.mean(values <= YAW_TOLERANCE))
    return figures


def _spaced(frames: np.ndarray, count: int) -> np.ndarray:
    """At most `count` of `frames`, evenly spaced."""
    return frames[:: max(1, len(frames) // count)][:count]


def split(
    recording: Recording, eval_frames: int, hold_out: str = "episodes", train_episodes: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Training frames (of the first 90% of episodes; with `hold_out` "kits" none whose kit a held-out episode has;
    the first `train_episodes` of those) and at most `eval_frames` evenly spaced held-out ones (the last 10%)."""
    episodes = np.unique(recording.episode_of)
    cut = episodes[int(len(episodes) * (1 - HELD_OUT))]
    held_episodes, pool = episodes[episodes >= cut], episodes[episodes < cut]
    if hold_out == "kits":
        held_kits = {recording.kit[int(e)] for e in held_episodes}
        pool = np.array([e for e in pool if recording.kit[int(e)] not in held_kits], dtype=episodes.dtype)
    if len(pool) == 0 or len(held_episodes) == 0:
        raise KitbenchError(
            f"{recording.root} has {len(episodes)} episodes, {len(pool)} of them to train on with --hold-out "
            f"{hold_out}; the probe needs at least one of each"
        )
    if train_episodes is not None:
        if not 1 <= train_episodes <= len(pool):
            raise KitbenchError(
                f"--train-episodes {train_episodes}: {recording.root.name} has {len(pool)} training episodes with "
                f"--hold-out {hold_out}; give 1..{len(pool)}"
            )
        pool = pool[:train_episodes]
    train = np.flatnonzero(np.isin(recording.episode_of, pool))
    held = np.flatnonzero(recording.episode_of >= cut)
    return train, _spaced(held, eval_frames)


def baselines(recording: Recording, train: np.ndarray, held: np.ndarray) -> dict:
    """What predicting the training frames' mean gets, what predicting each shape's own mean over its carried
    training frames gets (the yaw in the hand a policy knows from the shape alone), and what picking an empty
    pocket at random gets."""
    mean = recording.targets[train].mean(axis=0)
    figures = score(recording, held, np.array(np.broadcast_to(mean, (len(held), len(mean)))))
    shape_of_frame = np.array([recording.shape_of.get(int(e), -1) for e in recording.episode_of])
    carried = train[recording.lifted[train]] if recording.lifted is not None else train[:0]
    shapes = np.unique(shape_of_frame[carried])
    means = {s: recording.targets[carried[shape_of_frame[carried] == s]].mean(axis=0) for s in shapes}
    per_shape = np.array([means.get(shape_of_frame[f], mean) for f in held])
    chance = float(np.mean([1.0 / recording.empty[int(recording.episode_of[f])] for f in held]))
    return {"mean": figures, "shape_mean": score(recording, held, per_shape), "chance_right_slot": chance}


def train_and_score(
    recording: Recording,
    dataset,
    encoder_kind: str,
    shift: float,
    steps: int,
    batch: int,
    lr: float,
    checkpoints: list[int],
    train: np.ndarray,
    held: np.ndarray,
    seed: int = 1000,
    targets: tuple[str, ...] = DEFAULT_TARGETS,
    with_state: bool = False,
    seen: np.ndarray | None = None,
) -> tuple[dict, object]:
    """Train the encoder and head from scratch on the `train` frames, its loss over `targets` only; score the
    `held` ones at each of `checkpoints` (update counts), and the `seen` ones (training frames) under "seen".
    `with_state`: the arm's state, standardised, joins the encoder's features at the head. Returns the figures and
    the trained encoder."""
    import torch
    from torchvision.transforms import v2

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    encoder, width = build_encoder(encoder_kind, recording.image_shape)
    arm = recording.state if with_state else None
    if with_state and arm is None:
        raise KitbenchError(f"{recording.root}: --with-state needs the recording's {STATE}")
    head = torch.nn.Sequential(
        torch.nn.Linear(width * len(recording.cameras) + (arm.shape[1] if arm is not None else 0), HIDDEN),
        torch.nn.ReLU(),
        torch.nn.Linear(HIDDEN, 2 * len(targets)),
    )
    # the trained targets' columns, in TARGETS' order; an untrained target is predicted as its training mean
    trained = torch.tensor([c for t in TARGETS if t in targets for c in range(COLUMNS[t].start, COLUMNS[t].stop)])
    params = [*encoder.parameters(), *head.parameters()]
    optimizer = torch.optim.AdamW(params, lr=lr, weight_decay=1e-4)
    mu = torch.from_numpy(recording.targets[train].mean(axis=0))
    sigma = torch.from_numpy(recording.targets[train].std(axis=0) + 1e-6)
    stats = {
        cam: tuple(torch.from_numpy(a) for a in pair)
        for cam, pair in _image_stats(recording.root, recording.cameras).items()
    }
    shifter = v2.RandomAffine(degrees=0.0, translate=(shift, shift)) if shift > 0 else None
    arm_mu, arm_sigma = (arm[train].mean(axis=0), arm[train].std(axis=0) + 1e-6) if arm is not None else (0.0, 1.0)

    def inputs_of(frames: np.ndarray, augment: bool) -> tuple:
        """The frames' normalised images per camera, and their standardised arm state (None without it)."""
        items = [dataset[int(f)] for f in frames]
        per_camera = []
        for cam in recording.cameras:
            x = torch.stack([item[cam] for item in items])
            if augment and shifter is not None:
                x = torch.stack([shifter(img) for img in x])
            mean, std = stats[cam]
            per_camera.append((x - mean) / std)
        return per_camera, None if arm is None else torch.from_numpy((arm[frames] - arm_mu) / arm_sigma)

    from kitbench.training.precision import keep_cpu_amp

    bf16 = keep_cpu_amp()  # fp32 on a CPU without bf16, where the autocast is ~20x slower (docs/training.md)

    def forward(inputs: tuple):
        per_camera, state = inputs
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            features = [encoder(x).flatten(1) for x in per_camera]
            return head(torch.cat(features if state is None else [*features, state], dim=1)).float()

    def evaluate(scored: np.ndarray) -> dict:
        encoder.eval()
        head.eval()
        with torch.no_grad():
            out = []
            for i in range(0, len(scored), 64):
                frames = scored[i : i + 64]
                predicted = mu.repeat(len(frames), 1)
                predicted[:, trained] = forward(inputs_of(frames, augment=False)) * sigma[trained] + mu[trained]
                out.append(predicted)
        encoder.train()
        head.train()
        return score(recording, scored, torch.cat(out).numpy())

    marks: dict[int, dict] = {}
    update_seconds = 0.0
    for step in range(1, steps + 1):
        frames = rng.choice(train, size=batch)
        inputs = inputs_of(frames, augment=True)
        target = (torch.from_numpy(recording.targets[frames]) - mu) / sigma
        begin = time.perf_counter()
        loss = torch.nn.functional.l1_loss(forward(inputs), target[:, trained])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        update_seconds += time.perf_counter() - begin
        if step in checkpoints:
            marks[step] = {**evaluate(held), "train_l1": float(loss.detach())}
            if seen is not None:
                marks[step]["seen"] = evaluate(seen)
    return {"update_s": update_seconds / steps, "at": marks}, encoder


def write_starting_policy(config_path: Path, recording: Recording, encoder, out: Path) -> None:
    """An ACT policy as `config_path`'s `lerobot-train` would build it on this recording, its image backbone the
    probe's trained one, saved with its processors as a pretrained folder: `lerobot-train
    --config_path=<config> --policy.path=<out>` starts from it (the second stage of a two-stage training)."""
    import draccus
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    config = draccus.decode(PreTrainedConfig, json.loads(config_path.read_text())["policy"])
    config.device = "cpu"
    meta = LeRobotDatasetMetadata(recording.repo_id, root=recording.root)
    policy = make_policy(config, ds_meta=meta)
    policy.model.backbone.load_state_dict(encoder.backbone.state_dict())  # strict: the same ResNet-18
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=meta.stats)
    out.mkdir(parents=True, exist_ok=True)
    policy.save_pretrained(out)
    preprocessor.save_pretrained(out)
    postprocessor.save_pretrained(out)


def open_dataset(recording: Recording):
    """The recording as lerobot's `LeRobotDataset` serves it to `lerobot-train` (kitbench's reader, as the plugin
    installs it)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from kitbench.training import reader

    reader.install()
    return LeRobotDataset(recording.repo_id, root=recording.root)


def describe(m: dict, targets: tuple[str, ...]) -> str:
    """One checkpoint's figures of the trained targets, as the report prints them."""
    parts = {
        "goal": f"slot {m['goal_mm'][0]:5.1f} / {m['goal_mm'][1]:5.1f} mm, right slot {m['right_slot']:4.0%}",
        "yaw": f"yaw {m['yaw_deg']:5.1f} deg ({m['yaw_within_4deg']:4.0%} within 4)",
        "shape": f"shape {m['shape_mm']:5.1f} mm",
        "turn": f"turn {m['turn_deg']:5.1f} deg ({m['turn_within_4deg']:4.0%} within 4; "
        f"{m['turning_deg']:5.1f} turning, {m['carried_turn_deg']:5.1f} carried, {m['over_slot_turn_deg']:5.1f} over "
        f"the slot of {m['over_slot_frames']} frames)",
        "shape_yaw": f"shape yaw {m['shape_yaw_deg']:5.1f} deg ({m['shape_yaw_within_4deg']:4.0%} within 4)",
        "grip": f"yaw in the hand {m['grip_deg']:5.1f} deg ({m['grip_within_4deg']:4.0%} within 4; "
        f"{m['carried_grip_deg']:5.1f} carried)",
        "hand": f"hand over the slot {m['hand_deg']:5.1f} deg ({m['hand_within_4deg']:4.0%} within 4; "
        f"{m['carried_hand_deg']:5.1f} carried)",
    }
    return ", ".join(parts[t] for t in TARGETS if t in targets)


def parse_list(text: str, kind, name: str, valid: str) -> list:
    try:
        values = [kind(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values:
        raise KitbenchError(f"{name} {text!r} is not a comma-separated list of {valid}")
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("datasets", nargs="+", type=Path, help="AssemblingKits recordings with cameras")
    parser.add_argument("--encoders", default="act", help=f"comma-separated, of {', '.join(ENCODERS)}")
    parser.add_argument(
        "--shifts", default="0.05", help="training images' random shifts (share of a side), e.g. 0.05,0"
    )
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--checkpoints", help="update counts to score at (default: a quarter, half and the end)")
    parser.add_argument("--eval-frames", type=int, default=1000)
    parser.add_argument("--out", help="also write the figures to this JSON file")
    parser.add_argument(
        "--targets",
        default=",".join(DEFAULT_TARGETS),
        help=f"what the encoder is trained to read, of {', '.join(TARGETS)}",
    )
    parser.add_argument(
        "--with-state", action="store_true", help="the arm's state (joints, gripper) beside the images, at the head"
    )
    parser.add_argument(
        "--hold-out",
        default="episodes",
        help="what the held-out episodes keep out of training: episodes (themselves) or kits (every episode of "
        "their kits too)",
    )
    parser.add_argument(
        "--train-episodes", type=int, help="train on the first N training episodes only (default: all of them)"
    )
    parser.add_argument(
        "--save-policy",
        help="write an ACT policy whose backbone is the trained encoder, for lerobot-train --policy.path (one "
        "dataset, --encoders act, one shift)",
    )
    parser.add_argument("--policy-config", help="with --save-policy: the lerobot-train config the policy is built by")
    args = parser.parse_args(argv)
    try:
        encoders = parse_list(args.encoders, str, "--encoders", ", ".join(ENCODERS))
        for kind in encoders:
            if kind not in ENCODERS:
                raise KitbenchError(f"--encoders: unknown encoder {kind!r}; valid choices: {', '.join(ENCODERS)}")
        targets = tuple(parse_list(args.targets, str, "--targets", ", ".join(TARGETS)))
        for name in targets:
            if name not in TARGETS:
                raise KitbenchError(f"--targets: unknown target {name!r}; valid choices: {', '.join(TARGETS)}")
        shifts = parse_list(args.shifts, float, "--shifts", "numbers in 0..0.5")
        if any(not 0 <= s <= 0.5 for s in shifts):
            raise KitbenchError(f"--shifts {args.shifts!r}: each must be in 0..0.5")
        if args.hold_out not in HOLD_OUT:
            raise KitbenchError(f"--hold-out: unknown choice {args.hold_out!r}; valid choices: {', '.join(HOLD_OUT)}")
        if args.steps < 1 or args.batch < 1 or args.eval_frames < 1:
            raise KitbenchError("--steps, --batch and --eval-frames must be at least 1")
        default = sorted({max(1, args.steps // 4), max(1, args.steps // 2), args.steps})
        checkpoints = (
            default if args.checkpoints is None else parse_list(args.checkpoints, int, "--checkpoints", "update counts")
        )
        if any(not 1 <= c <= args.steps for c in checkpoints):
            raise KitbenchError(f"--checkpoints {args.checkpoints!r}: each must be in 1..--steps ({args.steps})")
        if args.save_policy:
            if len(args.datasets) != 1 or encoders != ["act"] or len(shifts) != 1:
                raise KitbenchError("--save-policy needs one dataset, --encoders act and one --shifts value")
            config = Path(args.policy_config or "")
            if not args.policy_config or not config.is_file():
                raise KitbenchError(f"--save-policy needs --policy-config, a lerobot-train config file; got {config}")
            try:
                policy_type = json.loads(config.read_text()).get("policy", {}).get("type")
            except (json.JSONDecodeError, AttributeError):
                raise KitbenchError(f"--policy-config {config} is not a lerobot-train config (JSON)") from None
            if policy_type != "act":
                raise KitbenchError(f"--policy-config {config} trains {policy_type!r}; the probe's encoder is ACT's")
        recordings = [read_recording(root) for root in args.datasets]
        splits = [split(r, args.eval_frames, args.hold_out, args.train_episodes) for r in recordings]
    except KitbenchError as exc:
        print(f"perception_probe: error: {exc}", file=sys.stderr)
        return 2
    rows = []
    for recording, (train, held) in zip(recordings, splits, strict=True):
        dataset = open_dataset(recording)
        seen = _spaced(train, len(held))
        base = baselines(recording, train, held)
        name = recording.root.name
        view = recording.camera_view or "default"
        trained_on = len(np.unique(recording.episode_of[train]))
        print(
            f"{name}: {recording.camera_size} {view} view, {', '.join(c[len(IMAGES) :] for c in recording.cameras)}; "
            f"{len(train)} training frames of {trained_on} episodes, {len(held)} held-out (held out: "
            f"{args.hold_out}); mean predictor: slot "
            f"{base['mean']['goal_mm'][0]:.0f} mm, right slot {base['mean']['right_slot']:.0%}, shape "
            f"{base['mean']['shape_mm']:.0f} mm, turn {base['mean']['turn_deg']:.0f} deg "
            f"({base['mean']['turning_deg']:.0f} turning, {base['mean']['over_slot_turn_deg']:.0f} over the slot), "
            f"shape yaw {base['mean']['shape_yaw_deg']:.0f} deg, "
            f"yaw in the hand {base['mean']['grip_deg']:.0f} deg ({base['mean']['carried_grip_deg']:.0f} carried; "
            f"each shape's mean: {base['shape_mean']['carried_grip_deg']:.0f}); an empty pocket at random: "
            f"right slot {base['chance_right_slot']:.0%}",
            flush=True,
        )
        for kind in encoders:
            for shift in shifts:
                result, encoder = train_and_score(
                    recording,
                    dataset,
                    kind,
                    shift,
                    args.steps,
                    args.batch,
                    args.lr,
                    checkpoints,
                    train,
                    held,
                    targets=targets,
                    with_state=args.with_state,
                    seen=seen,
                )
                if args.save_policy:
                    write_starting_policy(Path(args.policy_config), recording, encoder, Path(args.save_policy))
                    print(f"  starting policy: {args.save_policy}", flush=True)
                row = {
                    "dataset": name,
                    "camera_size": recording.camera_size,
                    "camera_view": view,
                    "encoder": kind,
                    "shift": shift,
                    "targets": list(targets),
                    "with_state": args.with_state,
                    "hold_out": args.hold_out,
                    "train_episodes": trained_on,
                    **result,
                    "baseline": base,
                }
                rows.append(row)
                label = f"{kind}+state" if args.with_state else kind
                for step, m in result["at"].items():
                    print(
                        f"  {label:<12} shift {shift:<5g} {step:>6} updates: {describe(m, targets)}, train L1 "
                        f"{m['train_l1']:.3f}\n  {'':<12} {'seen':<11} {'':>14}  {describe(m['seen'], targets)}",
                        flush=True,
                    )
                print(f"  {label:<12} shift {shift:<5g} {result['update_s']:.3f} s an update", flush=True)
    if args.out:
        Path(args.out).write_text(
            json.dumps({"steps": args.steps, "batch": args.batch, "lr": args.lr, "rows": rows}, indent=1) + "\n"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
