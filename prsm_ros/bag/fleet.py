"""Reports on many bags at once: one row of metrics per bag, in one table (`prsm-bag report DIR|GLOB`).

Each bag is reported by the single-bag report (`prsm_ros.bag.report.report`, no plots) and its
nested metrics are flattened to dotted column names (`tracking.rms_error_m`,
`efficiency.forward`, ...). With the `sweep` extra installed the bags are reported
as Ray tasks (an embedded Ray, or a cluster with `address`); without it, one after another in
this process: `.[bag]` does not need Ray. A bag that cannot be read is a row with status
"failed" and its error, never the end of the report.
"""

from __future__ import annotations

import glob
import importlib.util
import math
import time
from pathlib import Path

from prsm_ros.bag.reader import BagError

FLEET_TABLE = "fleet.parquet"
GLOB_CHARS = set("*?[")


def is_fleet(arg: str) -> bool:
    """A glob, or a directory that is not a single rosbag2 recording (one .mcap beside metadata.yaml)."""
    if GLOB_CHARS & set(arg):
        return True
    p = Path(arg)
    if not p.is_dir():
        return False
    own = list(p.glob("*.mcap"))
    return not (len(own) == 1 and not any(q.is_dir() for q in p.iterdir()))


def expand(arg: str) -> list[Path]:
    """The bags a directory (searched recursively) or a glob names, sorted; refused when there are none."""
    if GLOB_CHARS & set(arg):
        found = sorted(Path(p) for p in glob.glob(arg, recursive=True))
        files = [p for p in found if p.is_file() and p.suffix == ".mcap"]
        files += [m for p in found if p.is_dir() for m in sorted(p.rglob("*.mcap"))]
    else:
        files = sorted(Path(arg).rglob("*.mcap"))
    files = sorted(set(files))
    if not files:
        raise BagError(f"{arg}: no .mcap files found")
    return files


def flatten(d, prefix: str = "", out: dict | None = None) -> dict:
    """Nested report dict → {dotted.name: scalar}; lists and the plot paths are left out."""
    out = {} if out is None else out
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            flatten(v, name + ".", out)
        elif isinstance(v, bool):
            out[name] = float(v)
        elif isinstance(v, (int, float)):
            out[name] = float(v)
        elif v is None:
            out[name] = math.nan
        elif isinstance(v, str) and k in ("model", "preset", "note"):
            out[name] = v
    return out


def report_one(path: str, options: dict) -> dict:
    """One bag's metrics as a flat row; a bag that fails is a row with its error."""
    from prsm_ros.bag.reader import open_bag
    from prsm_ros.bag.report import report
    t0 = time.perf_counter()
    row: dict = {"bag": str(path)}
    try:
        r = report(open_bag(path), None, plots=False, progress=False, **options)
        row.update(flatten({k: v for k, v in r.items() if k not in ("bag", "topics", "plots")}))
        row["status"], row["error"] = "ok", None
    except Exception as e:  # noqa: BLE001 — a bad bag is data in a fleet, not the end of it
        row["status"], row["error"] = "failed", f"{type(e).__name__}: {e}"
    row["wall_time_s"] = time.perf_counter() - t0
    return row


def ray_available() -> bool:
    return importlib.util.find_spec("ray") is not None


def report_many(paths: list[Path], options: dict, *, address: str | None = None, use_ray: bool | None = None,
                workers: int | None = None, progress: bool = True) -> list[dict]:
    """Rows for every bag, in `paths` order: on Ray when it is installed (or `use_ray`), else in turn."""
    if address and not ray_available():
        raise BagError(f"--address {address}: reporting on a Ray cluster needs Ray: pip install 'prsm[sweep]'")
    use_ray = ray_available() if use_ray is None else use_ray
    from tqdm import tqdm
    bar = tqdm(total=len(paths), unit="bag", disable=not progress, desc="bags")
    try:
        if not use_ray:
            rows = []
            for p in paths:
                rows.append(report_one(str(p), options))
                bar.update(1)
            return rows
        from prsm_ros.ray_runner import RayUnavailable, connect, disconnect
        try:
            ray, owned, tmp = connect(address, workers)
        except RayUnavailable as e:  # Ray unreachable or not startable: the bag tools' one error family
            raise BagError(str(e)) from None
        try:
            task = ray.remote(num_cpus=1)(report_one)
            refs = {task.remote(str(p), options): i for i, p in enumerate(paths)}
            rows: list = [None] * len(paths)
            pending = list(refs)
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                for ref in ready:
                    rows[refs[ref]] = ray.get(ref)
                    bar.update(1)
            return rows
        finally:
            disconnect(ray, owned, tmp)
    finally:
        bar.close()


def write_rows(rows: list[dict], path: Path) -> Path:
    """One Parquet table of every bag's row (columns: the union of the rows' keys; pyarrow needed)."""
    from prsm_ros.bag.parquet import require_pyarrow, write_table
    pa, _ = require_pyarrow()
    names: list[str] = []
    for r in rows:
        names += [k for k in r if k not in names]
    cols = {}
    for n in names:
        vals = [r.get(n) for r in rows]
        if all(v is None or isinstance(v, float) for v in vals):
            cols[n] = pa.array([math.nan if v is None else v for v in vals], type=pa.float64())
        else:
            cols[n] = pa.array([None if v is None else str(v) for v in vals], type=pa.string())
    write_table(path, pa.table(cols))
    return path


def fleet_report(arg: str, out_dir, options: dict, *, address: str | None = None, use_ray: bool | None = None,
                 progress: bool = True) -> dict:
    """Report every bag `arg` names into `out_dir/fleet.parquet`; returns a summary."""
    paths = expand(arg)
    t0 = time.perf_counter()
    rows = report_many(paths, options, address=address, use_ray=use_ray, progress=progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    table = write_rows(rows, out / FLEET_TABLE)
    failed = [r for r in rows if r["status"] != "ok"]
    return {"bags": len(rows), "ok": len(rows) - len(failed), "failed": len(failed),
            "failures": [{"bag": r["bag"], "error": r["error"]} for r in failed],
            "engine": "ray" if (ray_available() if use_ray is None else use_ray) else "sequential",
            "table": str(table), "wall_time_s": time.perf_counter() - t0}
