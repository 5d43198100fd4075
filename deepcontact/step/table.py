"""A run as two flat tables, one row per body per step and one per contact point per step, for
pandas, R or a spreadsheet (`pandas.read_xml` cannot: a step file's values are attributes of
child elements). Columns: `seed`, `step`, `time`, then every array the step reader gives, a
2-vector split into `_x` and `_y` (docs/formats.md lists them)."""
import csv
import os

import numpy as np

from .. import atomic
from ..errors import InputError
from .reader import check_origin, read_step
from .run_folder import read_run

FORMATS = ("csv", "parquet")
TABLE_FILES = atomic.Owned("table export", [r"(bodies|contacts)\.(csv|parquet)"])


def _flat(arrays):
    """{column: 1-D array}: 2-vectors split into name_x, name_y."""
    out = {}
    for name, a in arrays.items():
        a = np.asarray(a)
        if a.ndim == 2:
            out[f"{name}_x"], out[f"{name}_y"] = a[:, 0], a[:, 1]
        else:
            out[name] = a
    return out


def step_rows(run_dir: str | os.PathLike, every: int = 1):
    """(seed, step, time, bodies columns, contacts columns) for every `every`-th step file of a run."""
    run = read_run(run_dir)
    for sim in run.simulations:
        for k, path in enumerate(sim.files):
            if k % every:
                continue
            header, bodies, contacts = read_step(path, validate=False)
            check_origin(header, sim.scene if sim.scene is not None else header["scene"], sim.seed, path)
            yield sim.seed, int(header["index"]), float(header["time"]), _flat(bodies), _flat(contacts)


def run_tables(run_dir: str | os.PathLike, every: int = 1) -> tuple[dict, dict]:
    """The run's bodies and contacts tables, in memory, as {column: numpy array}
    (`pandas.DataFrame(bodies)` makes a data frame of one)."""
    tables = ({}, {})
    for seed, step, time, *parts in step_rows(run_dir, every):
        for table, part in zip(tables, parts):
            n = len(next(iter(part.values()))) if part else 0
            for name, values in {"seed": np.full(n, seed), "step": np.full(n, step), "time": np.full(n, time),
                                 **part}.items():
                table.setdefault(name, []).append(values)
    return tuple({k: np.concatenate(v) for k, v in t.items()} for t in tables)


def export_tables(run_dir: str | os.PathLike, out: str | os.PathLike, *, fmt: str = "csv", every: int = 1,
                  overwrite: bool = False, progress=None) -> dict:
    """bodies.FMT and contacts.FMT in the folder out (atomically), streamed step by step; returns
    the row counts. Parquet needs pyarrow (the optional extra deepcontact[parquet])."""
    if fmt not in FORMATS:
        raise InputError(f"format must be one of {', '.join(FORMATS)}, not {fmt!r}")
    if fmt == "parquet":
        try:
            import pyarrow
            import pyarrow.parquet
        except ImportError:
            raise InputError("Parquet needs pyarrow, which is not installed: pip install 'deepcontact[parquet]' "
                             "(or pip install pyarrow), or export --format csv") from None
    rows = {"bodies": 0, "contacts": 0}
    with atomic.output_folder(out, TABLE_FILES, overwrite, command="export") as work:
        writers = {}
        try:
            for seed, step, time, bodies, contacts in step_rows(run_dir, every):
                if progress is not None:
                    progress.update(every)
                for name, part in (("bodies", bodies), ("contacts", contacts)):
                    n = len(next(iter(part.values())))
                    columns = {"seed": np.full(n, seed), "step": np.full(n, step), "time": np.full(n, time), **part}
                    if name not in writers:
                        writers[name] = _writer(work / f"{name}.{fmt}", fmt, columns)
                    writers[name].write(columns, n)
                    rows[name] += n
        finally:
            for w in writers.values():
                w.close()
    return rows


class _CSV:
    def __init__(self, path, columns):
        self.f = open(path, "w", newline="")
        self.w = csv.writer(self.f)
        self.w.writerow(list(columns))

    def write(self, columns, n):
        text = {k: v.tolist() for k, v in columns.items()}   # (repr of float64/float32 values, exact)
        self.w.writerows(zip(*text.values()))

    def close(self):
        self.f.close()


class _Parquet:
    def __init__(self, path, columns):
        import pyarrow.parquet as pq
        self.pq = pq
        self.writer = None
        self.path = path

    def write(self, columns, n):
        import pyarrow as pa
        table = pa.table(columns)
        if self.writer is None:
            self.writer = self.pq.ParquetWriter(self.path, table.schema)
        self.writer.write_table(table)

    def close(self):
        if self.writer is not None:
            self.writer.close()


def _writer(path, fmt, columns):
    return _CSV(path, columns) if fmt == "csv" else _Parquet(path, columns)
