"""A LeRobot dataset's table columns as numpy arrays, served as stock `LeRobotDataset` serves a row.

Stock reads each row through `datasets` and converts every value with `torch.tensor` (lerobot's
`hf_transform_to_torch`): floats come back float32, integers int64, booleans bool, a (1,)-shaped feature as a
0-d tensor. The arrays here hold the columns already in those dtypes, so a row is a few numpy indexings.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import torch

# numpy kind -> the dtype `torch.tensor` gives the Python values `datasets` returns for it
_TORCH_DTYPE = {"f": np.float32, "i": np.int64, "u": np.int64, "b": np.bool_}


class UnsupportedColumn(Exception):
    """A column this reader does not hold (variable-length lists, strings, structs): the stock reader serves it."""


def column_array(column: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """A fixed-shape column (scalars, fixed-length lists, `datasets` ArrayND) as one numpy array, one row per
    entry, in the dtype stock hands the trainer."""
    array = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    if isinstance(array, pa.ExtensionArray):
        array = array.storage
    shape: list[int] = []
    while pa.types.is_list(array.type) or pa.types.is_fixed_size_list(array.type):
        sizes = np.diff(array.offsets.to_numpy()) if pa.types.is_list(array.type) else None
        if sizes is not None and (len(sizes) == 0 or np.any(sizes != sizes[0])):
            raise UnsupportedColumn(f"variable-length lists ({array.type})")
        size = int(sizes[0]) if sizes is not None else array.type.list_size
        if array.null_count:
            raise UnsupportedColumn("missing values")
        shape.append(size)
        array = array.flatten()
    kind = array.type.to_pandas_dtype()
    try:
        dtype = _TORCH_DTYPE[np.dtype(kind).kind]
    except (KeyError, TypeError) as exc:
        raise UnsupportedColumn(f"type {array.type}") from exc
    if array.null_count:
        raise UnsupportedColumn("missing values")
    values = array.to_numpy(zero_copy_only=False).astype(dtype, copy=False)
    rows = len(values) // max(1, int(np.prod(shape))) if shape else len(values)
    return np.ascontiguousarray(values.reshape(rows, *shape))


class Columns:
    """Named columns of one table, row-aligned (row i of every array is the table's row i)."""

    def __init__(self, arrays: dict[str, np.ndarray]):
        self.arrays = arrays

    @classmethod
    def from_table(cls, table: pa.Table, names: list[str]) -> Columns:
        return cls({name: column_array(table.column(name)) for name in names})

    def row(self, index: int) -> dict[str, torch.Tensor]:
        """Row `index` of every column, each value a tensor of its own (never a view into the arrays)."""
        return {name: torch.from_numpy(np.array(array[index])) for name, array in self.arrays.items()}

    def rows(self, name: str, indices: np.ndarray) -> torch.Tensor:
        """Rows `indices` of one column, stacked."""
        return torch.from_numpy(self.arrays[name][indices])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def __contains__(self, name: Any) -> bool:
        return name in self.arrays
