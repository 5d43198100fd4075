"""A run as two flat tables, one row per body per step and one per contact point per step, for
pandas, R or a spreadsheet (`pandas.read_xml` cannot: a step file's values are attributes of
child elements). Columns: `seed`, `step`, `time`, then every array the step reader gives, a
2-vector split into `_x` and `_y` (docs/formats.md lists them); a Box2D 2.4.1 run's tables leave
out Box2D v3's columns and a v3 run's leave out 2.4.1's (what the engine does not record)."""
import os

import numpy as np

from .. import arguments, output, workers
from ..errors import InputError
from ..escape import CsvWriter
from .engines import foreign_fields, rows_of
from .reader import check_origin, read_step
from .run_folder import read_run

FORMATS = ("csv", "parquet")
TABLE_FILES = output.Owned("table export", [r"(bodies|contacts)\.(csv|parquet)"])


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


def step_tables(run_dir: str | os.PathLike, every: int = 1, jobs: int = 1, progress=None):
    """For every `every`-th step file of a run, in order, {"bodies": columns, "contacts": columns}:
    each {column: 1-D array}, beginning with seed, step and time. jobs > 1: read in worker
    processes (the same tables). progress(n): n more step files read."""
    every = arguments.whole(every, "every", 1)
    run = read_run(arguments.path(run_dir, "run_dir"))
    tasks = [(path, (sim.scene, sim.engine), sim.seed) for sim in run.simulations for path in sim.files[::every]]
    with workers.for_jobs(jobs, tasks, progress) as pool:
        yield from pool.imap(_step_columns, tasks)


def _step_columns(task):
    path, (scene, engine), seed = task
    header, bodies, contacts = read_step(path, validate=False)
    check_origin(header, scene if scene is not None else header["scene"], seed, path, engine)
    out = {}
    foreign = foreign_fields(rows_of(header["solver"].get("name")))   # (other engines' columns: not recorded)
    contacts = {k: v for k, v in contacts.items() if k not in foreign}
    for name, arrays in (("bodies", bodies), ("contacts", contacts)):
        n = len(next(iter(arrays.values())))
        out[name] = {"seed": np.full(n, seed), "step": np.full(n, int(header["index"])),
                     "time": np.full(n, float(header["time"])), **_flat(arrays)}
    workers.progress(1)
    return out


def run_tables(run_dir: str | os.PathLike, every: int = 1) -> tuple[dict, dict]:
    """The run's bodies and contacts tables, in memory, as {column: numpy array}
    (`pandas.DataFrame(bodies)` makes a data frame of one)."""
    parts = {"bodies": {}, "contacts": {}}
    for step in step_tables(run_dir, every):
        for name, columns in step.items():
            for column, values in columns.items():
                parts[name].setdefault(column, []).append(values)
    return tuple({k: np.concatenate(v) for k, v in parts[name].items()} for name in ("bodies", "contacts"))


def export_tables(run_dir: str | os.PathLike, out: str | os.PathLike, *, fmt: str = "csv", every: int = 1,
                  overwrite: bool = False, progress=None, jobs: int = 1) -> dict:
    """bodies.FMT and contacts.FMT in the folder out (atomically), streamed step by step; returns
    the row counts. Parquet needs pyarrow (the optional extra deepcontact[parquet]). jobs > 1:
    steps read in worker processes (the same bytes). progress(n): n more step files read."""
    if fmt not in FORMATS:
        raise InputError(f"format must be one of {', '.join(FORMATS)}, not {fmt!r}")
    if fmt == "parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise InputError("Parquet needs pyarrow, which is not installed: pip install pyarrow, "
                             "or export --format csv") from None
    rows = {"bodies": 0, "contacts": 0}
    with output.output_folder(out, TABLE_FILES, overwrite, command="export") as work:
        writers = {}
        try:
            for step in step_tables(run_dir, every, jobs, progress):
                for name, columns in step.items():
                    if name not in writers:
                        writers[name] = (_CSV if fmt == "csv" else _Parquet)(work / f"{name}.{fmt}")
                    writers[name].write(columns)
                    rows[name] += len(columns["seed"])
        finally:
            for w in writers.values():
                w.close()
    return rows


class _CSV:
    """Rows appended as they come (the values' repr: float32 values as the doubles they are)."""

    def __init__(self, path):
        self.f = output.open_new(path, "w")
        self.w = CsvWriter(self.f)
        self.header = False

    def write(self, columns):
        if not self.header:
            self.w.writerow(list(columns))
            self.header = True
        self.w.writerows(zip(*(v.tolist() for v in columns.values())))

    def close(self):
        self.f.close()


class _Parquet:
    """One row group a step; the schema is the first step's."""

    def __init__(self, path):
        self.path, self.writer = path, None

    def write(self, columns):
        import pyarrow as pa
        import pyarrow.parquet as pq
        table = pa.table(columns)
        if self.writer is None:
            self.writer = pq.ParquetWriter(self.path, table.schema)
        self.writer.write_table(table)

    def close(self):
        if self.writer is not None:
            self.writer.close()
