"""How LeRobot stores each feature of a dataset in its data files: the Hugging Face feature it writes a column as
(`get_hf_features_from_features`) and the arrow type that column reads back as, computed without importing lerobot
so that `kitbench.integrity` can check a data file's schema from its footer. tests/test_lerobot_coupling.py
compares these with the installed LeRobot's."""

from __future__ import annotations

from typing import Any


def hf_feature(entry: dict) -> dict | None:
    """The Hugging Face feature LeRobot writes a data column of feature `entry` as (`get_hf_features_from_features`,
    its `shape=(1,)` columns saved as values), without importing lerobot; None for a video (not in the data)."""
    dtype, shape = entry["dtype"], entry["shape"]
    if dtype == "video":
        return None
    if dtype == "image":
        return {"_type": "Image"}
    if shape == [1]:
        return {"dtype": dtype, "_type": "Value"}
    if len(shape) == 1:
        return {"feature": {"dtype": dtype, "_type": "Value"}, "length": shape[0], "_type": "List"}
    return {"shape": shape, "dtype": dtype, "_type": f"Array{len(shape)}D"}


def stored_form(feature: Any) -> Any:
    """A stored Hugging Face feature in the form `hf_feature` gives: a one-element list as its value, a
    `Sequence` (older `datasets`) as a `List`, an image by its type, shapes as lists."""
    if not isinstance(feature, dict):
        return feature
    kind = feature.get("_type")
    if kind == "Image":
        return {"_type": "Image"}
    if kind in ("List", "Sequence"):
        inner = stored_form(feature.get("feature"))
        if feature.get("length") == 1 and isinstance(inner, dict) and inner.get("_type") == "Value":
            return inner
        return {"feature": inner, "length": feature.get("length"), "_type": "List"}
    if isinstance(kind, str) and kind.startswith("Array"):
        return {"shape": list(feature.get("shape") or []), "dtype": feature.get("dtype"), "_type": kind}
    return feature


def from_arrow(kind: Any) -> Any:
    """What a column's arrow type says of its feature, in `arrow_view`'s terms."""
    import pyarrow as pa

    if pa.types.is_struct(kind):
        return "image" if kind.get_field_index("bytes") >= 0 else str(kind)
    if pa.types.is_fixed_size_list(kind):
        return (from_arrow(kind.value_type), kind.list_size)
    if pa.types.is_list(kind) or pa.types.is_large_list(kind):
        return (from_arrow(kind.value_type), None)
    return str(kind)


def fits(stored: Any, expected: Any) -> bool:
    """An arrow type's view fits a feature's: equal, where a list of unstated length fits any length."""
    if isinstance(stored, tuple) and isinstance(expected, tuple):
        return fits(stored[0], expected[0]) and stored[1] in (None, expected[1])
    return stored == expected


_ARROW_NAMES = {"float32": "float", "float64": "double", "string": "string"}


def arrow_view(feature: dict) -> Any:
    """A Hugging Face feature (`hf_feature`) as `from_arrow` reads its column's arrow type."""
    kind = feature["_type"]
    if kind == "Image":
        return "image"
    if kind == "Value":
        return _ARROW_NAMES.get(feature["dtype"], feature["dtype"])
    if kind == "List":
        return (arrow_view(feature["feature"]), feature["length"])
    inner: Any = _ARROW_NAMES.get(feature["dtype"], feature["dtype"])
    for _ in feature["shape"]:
        inner = (inner, None)
    return inner
