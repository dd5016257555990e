"""Campaign results on disk: one Parquet file per chunk of completed cases, with provenance.

Files are written atomically (temporary name, then rename), so an interrupted campaign leaves only
whole chunks; :func:`done_case_hashes` reads them back to resume. Every file carries the spec, the
package version, the git revision and the library versions in its schema metadata
(``taiji2.*`` keys), so a table found later says where it came from.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import uuid
from collections.abc import Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

ROW_SCHEMA = pa.schema([
    ("case_hash", pa.string()), ("group", pa.string()), ("layout", pa.string()), ("duration_s", pa.float64()),
    ("seed", pa.int64()), ("method", pa.string()), ("overrides", pa.string()), ("effects", pa.string()),
    ("config_hash", pa.string()), ("parameter", pa.string()), ("unit", pa.string()), ("estimate", pa.float64()),
    ("sigma", pa.float64()), ("truth", pa.float64()), ("error", pa.float64()), ("crlb", pa.float64()),
    ("nis_mean", pa.float64()), ("diagnosis", pa.string()), ("compute_s", pa.float64()),
    ("status", pa.string()), ("error_message", pa.string()),
    ("fidelity", pa.string()), ("model_overrides", pa.string()), ("nis_band", pa.float64()),
    ("noise_adjusted", pa.bool_()),
])
LIBRARIES = ("numpy", "scipy", "dask", "distributed", "pyarrow", "taiji2_sim_pkg", "taiji2_estimator_pkg")


def provenance(spec: Mapping[str, Any]) -> dict[str, str]:
    """Metadata stored in every chunk: spec, versions, git revision, host Python."""
    versions = {}
    for name in LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return {"taiji2.spec": json.dumps(spec, sort_keys=True, default=str),
            "taiji2.version": versions["taiji2_estimator_pkg"],
            "taiji2.git_revision": _git_revision(),
            "taiji2.libraries": json.dumps(versions, sort_keys=True),
            "taiji2.python": platform.python_version()}


def write_chunk(out_dir: Path, results: Sequence[Mapping[str, Any]], meta: Mapping[str, str]) -> Path:
    """Write the rows of completed cases (failed cases as one row each) as one Parquet file."""
    rows: list[dict[str, Any]] = []
    for result in results:
        if result["status"] == "ok":
            rows += [{**row, "status": "ok", "error_message": ""} for row in result["rows"]]
        else:
            rows.append({"case_hash": result["case_hash"], "group": result.get("group", ""),
                         "seed": result.get("seed"), "compute_s": result["compute_s"], "status": "error",
                         "error_message": result["error"]})
    table = pa.Table.from_pylist(rows, schema=ROW_SCHEMA).replace_schema_metadata(dict(meta))
    out_dir.mkdir(parents=True, exist_ok=True)
    name = f"chunk-{uuid.uuid4().hex[:12]}.parquet"
    tmp = out_dir / f".{name}.tmp"
    pq.write_table(table, tmp)
    os.replace(tmp, out_dir / name)
    return out_dir / name


def chunk_files(out_dir: Path) -> list[Path]:
    """The complete chunk files of a campaign directory."""
    return sorted(Path(out_dir).glob("chunk-*.parquet"))


def done_case_hashes(out_dir: Path) -> set[str]:
    """Hashes of the cases already recorded (finished or failed) in ``out_dir``."""
    done: set[str] = set()
    for path in chunk_files(out_dir):
        done.update(pq.read_table(path, columns=["case_hash"]).column("case_hash").to_pylist())
    return done


def read_rows(out_dir: Path) -> pa.Table:
    """All rows of a campaign directory as one Arrow table (``.to_pandas()`` for pandas).

    Raises
    ------
    FileNotFoundError
        If the directory holds no chunk file.
    """
    files = chunk_files(out_dir)
    if not files:
        raise FileNotFoundError(f"{str(out_dir)!r}: no campaign chunk files (chunk-*.parquet)")
    return pa.concat_tables([pq.read_table(path, schema=ROW_SCHEMA) for path in files])


def _git_revision() -> str:
    # the working directory first (a user runs from the repository), then the installed sources
    for where in (Path.cwd(), Path(__file__).resolve().parent):
        try:
            proc = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, timeout=5)
        except (OSError, subprocess.SubprocessError):
            continue
        if proc.returncode == 0:
            return proc.stdout.strip()
    return "unknown"
