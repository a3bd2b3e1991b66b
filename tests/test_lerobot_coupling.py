"""kitbench's coupling to LeRobot's internals, held to the installed lerobot rather than to the version pin: every
attribute of lerobot's dataset reader that `FastReader` reads (found in its code, so a new one is not missed), the
reader methods it calls through `super()`, the module names `install()` replaces, and every constant and the
feature conversion `kitbench.integrity` copies to check a dataset without importing lerobot. What moved fails in
one line naming it."""

from __future__ import annotations

import ast
import inspect
from importlib.metadata import version

import numpy as np
import pytest

FEATURES = {  # the shapes and dtypes kitbench records, and an image
    "observation.state": {"dtype": "float32", "shape": (3,), "names": None},
    "observation.grid": {"dtype": "float32", "shape": (2, 3), "names": None},
    "observation.cube": {"dtype": "uint8", "shape": (2, 2, 3), "names": None},
    "action": {"dtype": "float32", "shape": (2,), "names": None},
    "episode_seed": {"dtype": "int64", "shape": (1,), "names": None},
    "next.success": {"dtype": "bool", "shape": (1,), "names": None},
}


def _moved(what: list[str]) -> None:
    if what:
        pytest.fail(f"lerobot {version('lerobot')} moved what kitbench relies on: {'; '.join(what)}", pytrace=False)


@pytest.fixture(scope="module")
def lerobot_dataset(tmp_path_factory):
    """Two episodes that lerobot itself wrote, state only (no video to encode)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path_factory.mktemp("lerobot") / "dataset"
    dataset = LeRobotDataset.create("kitbench/coupling", fps=10, features=FEATURES, root=root, use_videos=False)
    for episode in range(2):
        for step in range(3):
            frame = {k: np.full(f["shape"], step + episode, dtype=f["dtype"]) for k, f in FEATURES.items()}
            dataset.add_frame({**frame, "task": "lift"})
        dataset.save_episode()
    dataset.finalize()
    return root


def _is_super(call: ast.Call) -> bool:
    return isinstance(call.func, ast.Name) and call.func.id == "super"


def _fast_reader_reads() -> tuple[set[str], set[str]]:
    """The attributes `FastReader`'s code reads from lerobot's reader (`self.x` it does not set or define itself,
    and `READER_ATTRIBUTES`), and the methods it calls on it through `super()`."""
    from kitbench.training import reader

    tree = ast.parse(inspect.getsource(reader.FastReader))
    own, read, inherited = set(), set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            own.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self":
            (own if isinstance(node.ctx, ast.Store) else read).add(node.attr)
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Call) and _is_super(node.value):
            inherited.add(node.attr)
    read = {name for name in read - own if not name.startswith("__")}
    return read | set(reader.READER_ATTRIBUTES.values()), inherited


def test_every_reader_attribute_fast_reader_reads_is_lerobots(lerobot_dataset):
    from lerobot.datasets.dataset_reader import DatasetReader
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    reads, inherited = _fast_reader_reads()
    assert {"_absolute_to_relative_idx", "_image_transforms"} <= reads  # the scan finds what the code reads
    stock = LeRobotDataset("kitbench/coupling", root=lerobot_dataset).reader
    assert isinstance(stock, DatasetReader) and stock.hf_dataset is not None
    missing = [f"DatasetReader.{name} (FastReader reads it)" for name in sorted(reads) if not hasattr(stock, name)]
    missing += [
        f"DatasetReader.{name}() (FastReader calls it through super())"
        for name in sorted(inherited)
        if not callable(getattr(DatasetReader, name, None))
    ]
    _moved(missing)


def test_the_module_names_install_replaces_are_lerobots():
    from lerobot.datasets import factory, lerobot_dataset

    from kitbench.training import reader

    replaced = [
        (target.value.id, target.attr)
        for node in ast.walk(ast.parse(inspect.getsource(reader.install)))
        if isinstance(node, ast.Assign)
        for target in node.targets
        if isinstance(target, ast.Attribute) and isinstance(target.value, ast.Name)
    ]
    modules = {"lerobot_dataset": lerobot_dataset, "dataset_factory": factory}
    assert {module for module, _ in replaced} == set(modules) and len(replaced) == 3
    _moved([f"{modules[m].__name__}.{name}" for m, name in replaced if not hasattr(modules[m], name)])
    # lerobot looks the reader up in its module at each build, so the replacement takes
    source = inspect.getsource(lerobot_dataset)
    _moved([] if "DatasetReader(" in source else [f"{lerobot_dataset.__name__} builds no DatasetReader by name"])


def test_the_constants_integrity_copies_are_lerobots():
    from lerobot.datasets import dataset_metadata, utils
    from lerobot.utils.constants import DEFAULT_FEATURES

    from kitbench import integrity, metadata

    pairs = [
        ("kitbench.integrity.CODEBASE_VERSION", integrity.CODEBASE_VERSION, dataset_metadata.CODEBASE_VERSION),
        ("kitbench.metadata.INFO_FILE", metadata.INFO_FILE, utils.INFO_PATH),
        ("kitbench.integrity.STATS_FILE", integrity.STATS_FILE, utils.STATS_PATH),
        ("kitbench.integrity.TASKS_FILE", integrity.TASKS_FILE, utils.DEFAULT_TASKS_PATH),
        ("kitbench.integrity.EPISODES_DIR", integrity.EPISODES_DIR, utils.EPISODES_DIR),
        ("kitbench.integrity.INDEX_COLUMNS", sorted(integrity.INDEX_COLUMNS), sorted(DEFAULT_FEATURES)),
    ]
    moved = [f"{name} is {mine!r}, lerobot's {theirs!r}" for name, mine, theirs in pairs if mine != theirs]
    # the placeholders `_info` requires of the paths lerobot writes
    for template, keys in ((utils.DEFAULT_DATA_PATH, ("{chunk_index", "{file_index")), (utils.DEFAULT_VIDEO_PATH,
                           ("{video_key", "{file_index"))):  # fmt: skip
        moved += [f"lerobot's path {template!r} has no {key}" for key in keys if key not in template]
    _moved(moved)


@pytest.mark.parametrize("dtype", ["float32", "int64", "bool"])
def test_integrity_converts_each_feature_as_lerobot_does(dtype):
    from lerobot.datasets.feature_utils import get_hf_features_from_features

    from kitbench import lerobot_schema

    features = {f"f{len(shape)}_{n}": {"dtype": dtype, "shape": shape, "names": None}
                for n, shape in enumerate([(1,), (7,), (2, 3), (2, 3, 4), (1, 2, 3, 4), (1, 1, 2, 3, 4)])}  # fmt: skip
    features["camera"] = {"dtype": "image", "shape": (8, 8, 3), "names": None}
    features["video"] = {"dtype": "video", "shape": (8, 8, 3), "names": None}
    theirs = get_hf_features_from_features(features)
    moved = []
    for name, entry in features.items():
        mine = lerobot_schema.hf_feature({**entry, "shape": list(entry["shape"])})  # as info.json reads
        stored = lerobot_schema.stored_form(theirs.to_dict()[name]) if name in theirs else None
        if mine != stored:
            moved.append(f"{entry['dtype']} {entry['shape']}: lerobot writes {stored}, kitbench expects {mine}")
        elif mine is not None:  # a file pandas wrote (lerobot's aggregation): the arrow type an array is stored as
            kind = theirs.arrow_schema.field(name).type
            arrow = lerobot_schema.from_arrow(getattr(kind, "storage_type", kind))
            if not lerobot_schema.fits(arrow, lerobot_schema.arrow_view(mine)):
                moved.append(f"{entry['dtype']} {entry['shape']}: lerobot's arrow type {arrow}")
    _moved(moved)


def test_a_dataset_lerobot_writes_reads_whole_to_integrity(lerobot_dataset):
    """The meta files, episode columns and feature schema `check_dataset` reads, as lerobot writes them."""
    from kitbench.integrity import Damage, check_dataset

    try:
        check_dataset(lerobot_dataset)
    except Damage as exc:
        _moved([f"check_dataset refuses what lerobot wrote: {exc}"])
