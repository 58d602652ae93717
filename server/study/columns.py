"""Typed tables, with no study in them: a column's declared name, type, unit and meaning (``Column``), a table's
columns in order (``Table``), and the one way a table is written and read back with those types.

``conform`` turns rows into a DataFrame of exactly the declared columns, in order, each cast to its type (a value
outside its type or its categories is an error, never a silent NaN); ``read_csv`` and ``read_parquet`` read a table
back with its types (a table without rows too), from ``schema.json`` beside the CSV files or the Parquet file's own
metadata; ``check_frame`` / ``check_arrow`` say how a table read back differs from its declaration.
``server.study.schema`` declares the study's tables with these.

Types (``Column.type``), as pandas dtypes and Arrow types:

| type | pandas | Arrow | missing values |
|---|---|---|---|
| ``int64`` | ``int64`` | ``int64`` | none |
| ``Int64`` | ``Int64`` (nullable) | ``int64`` | ``<NA>`` |
| ``float64`` | ``float64`` | ``double`` | ``NaN`` |
| ``bool`` | ``bool`` | ``bool`` | none |
| ``boolean`` | ``boolean`` (nullable) | ``bool`` | ``<NA>`` |
| ``string`` | ``string`` | ``string`` | ``<NA>`` |
| ``category`` | ``category`` (the declared categories) | ``dictionary<int32, string>`` | ``NaN`` |
| ``timestamp`` | ``datetime64[us, UTC]`` | ``timestamp[us, tz=UTC]`` | ``NaT`` |
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pyarrow as pa

SCHEMA_FILE = "schema.json"
"""The CSV files' types, written beside them."""


@dataclass(frozen=True)
class Kind:
    """A column type as a pandas dtype and an Arrow type, and whether it holds missing values."""

    pandas: str
    arrow: pa.DataType
    nullable: bool


TYPES: dict[str, Kind] = {
    "int64": Kind("int64", pa.int64(), False),
    "Int64": Kind("Int64", pa.int64(), True),
    "float64": Kind("float64", pa.float64(), True),
    "bool": Kind("bool", pa.bool_(), False),
    "boolean": Kind("boolean", pa.bool_(), True),
    "string": Kind("string", pa.string(), True),
    "category": Kind("category", pa.dictionary(pa.int32(), pa.string()), True),
    "timestamp": Kind("datetime64[us, UTC]", pa.timestamp("us", tz="UTC"), True),
}


@dataclass(frozen=True)
class Column:
    """One column of an exported table."""

    name: str
    type: str
    """A key of ``TYPES``."""
    unit: str
    """The unit of a number, or what a text holds (empty where none applies)."""
    description: str
    categories: tuple = ()
    """``category``: every value it may take, in order (none for a study that has none: a study without questions
    has no question ids, and its column stays empty)."""

    def __post_init__(self):
        if self.type not in TYPES:
            raise ValueError(f"column {self.name}: type {self.type!r} is not one of {list(TYPES)}")
        if self.categories and self.type != "category":
            raise ValueError(f"column {self.name}: categories are for type 'category' only")

    @property
    def nullable(self) -> bool:
        return TYPES[self.type].nullable

    def pandas_dtype(self):
        if self.type == "category":
            return pd.CategoricalDtype([str(c) for c in self.categories])
        return pd.api.types.pandas_dtype(TYPES[self.type].pandas)

    def arrow_field(self) -> pa.Field:
        meta = {"type": self.type, "unit": self.unit, "description": self.description}
        if self.type == "category":
            meta["categories"] = json.dumps([str(c) for c in self.categories])
        return pa.field(self.name, TYPES[self.type].arrow, nullable=self.nullable, metadata=meta)

    def as_dict(self) -> dict:
        out = {"name": self.name, "type": self.type, "pandas_dtype": TYPES[self.type].pandas,
               "arrow_type": str(TYPES[self.type].arrow), "nullable": self.nullable, "unit": self.unit,
               "description": self.description}
        if self.type == "category":
            out["categories"] = [str(c) for c in self.categories]
        return out


@dataclass(frozen=True)
class Table:
    """An exported table: what a row is, its columns in order, and the columns that name one row."""

    name: str
    row: str
    columns: tuple[Column, ...]
    unique: tuple[str, ...] = ()
    """Columns whose values no two rows share (a table's key); ``conform`` refuses a table that breaks it."""

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.columns]

    def arrow_schema(self, metadata: dict | None = None) -> pa.Schema:
        return pa.schema([c.arrow_field() for c in self.columns], metadata=metadata)


def conform(rows: list[dict], table: Table) -> pd.DataFrame:
    """``rows`` as a DataFrame of exactly the declared columns, in order, each of its declared type. A column
    the rows have and the table does not, a missing value in a column that allows none, or a value outside its
    categories raises ``ValueError`` naming the table, the column and the value."""
    extra = sorted({k for r in rows for k in r} - set(table.names))
    if extra:
        raise ValueError(f"{table.name}: columns {extra} are not declared in server/study/schema.py")
    frame = pd.DataFrame(rows, columns=table.names)
    if table.unique:
        repeated = frame[frame.duplicated(list(table.unique), keep=False)]
        if len(repeated):
            first = ", ".join(f"{c}={repeated.iloc[0][c]}" for c in table.unique)
            raise ValueError(f"{table.name}: {len(repeated)} rows share their ({', '.join(table.unique)}), which names "
                             f"one row; the first: {first}")
    out = {}
    for column in table.columns:
        values = frame[column.name]
        if not column.nullable and values.isna().any():
            raise ValueError(f"{table.name}.{column.name}: a missing value in a column of type {column.type}")
        if column.type == "category":
            values = values.map(lambda v: v if v is None or v != v else str(v))
            unknown = sorted(set(values.dropna()) - {str(c) for c in column.categories})
            if unknown:
                raise ValueError(f"{table.name}.{column.name}: {unknown} not among its categories "
                                 f"{list(column.categories)}")
        elif column.type in ("Int64", "int64", "boolean", "bool"):
            values = values.astype(object).where(values.notna(), None)
        out[column.name] = values.astype(column.pandas_dtype())
    return pd.DataFrame(out, columns=table.names)

def read_csv(folder: str | Path, name: str) -> pd.DataFrame:
    """A table's CSV file read back with its declared types (from ``schema.json`` beside it)."""
    folder = Path(folder)
    columns = json.loads((folder / SCHEMA_FILE).read_text())["tables"][name]["columns"]
    times = [c["name"] for c in columns if c["type"] == "timestamp"]
    dtypes = {c["name"]: pd.CategoricalDtype(c["categories"]) if c["type"] == "category" else c["pandas_dtype"]
              for c in columns if c["type"] != "timestamp"}
    # only an empty field is missing: a text answer "NA" or "null" stays text
    frame = pd.read_csv(folder / f"{name}.csv", dtype=dtypes, keep_default_na=False, na_values=[""])
    for n in times:
        frame[n] = pd.to_datetime(frame[n], utc=True, format="ISO8601").astype("datetime64[us, UTC]")
    return frame


def read_parquet(folder: str | Path, name: str) -> pd.DataFrame:
    """A table's Parquet file read back with its declared types, as ``read_csv`` reads its CSV file.

    ``pd.read_parquet`` gives them too, but for the categories of a table without rows: Parquet keeps a column's
    dictionary with its values, so a file of no rows holds none. Each category column's field in the file names its
    categories (its ``categories`` metadata), and they are given back here."""
    import pyarrow.parquet as pq

    path = Path(folder) / f"{name}.parquet"
    frame = pd.read_parquet(path)
    for field in pq.read_schema(path):
        named = (field.metadata or {}).get(b"categories")
        if named is not None:
            frame[field.name] = frame[field.name].astype(pd.CategoricalDtype(json.loads(named)))
    return frame


def check_frame(frame: pd.DataFrame, table: Table) -> list[str]:
    """How a DataFrame read back differs from the declaration (empty: it matches)."""
    if list(frame.columns) != table.names:
        return [f"{table.name}: columns {list(frame.columns)} != declared {table.names}"]
    return [f"{table.name}.{c.name}: {frame[c.name].dtype} != declared {c.pandas_dtype()}"
            for c in table.columns if frame[c.name].dtype != c.pandas_dtype()]


def check_arrow(schema: pa.Schema, table: Table) -> list[str]:
    """How an Arrow schema (a Parquet file's) differs from the declaration (empty: it matches)."""
    if schema.names != table.names:
        return [f"{table.name}: columns {schema.names} != declared {table.names}"]
    return [f"{table.name}.{c.name}: {schema.field(c.name).type} != declared {TYPES[c.type].arrow}"
            for c in table.columns if schema.field(c.name).type != TYPES[c.type].arrow]

