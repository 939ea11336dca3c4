"""How long mesh files take to read (clrender/mesh_files.py): binary PLY, ASCII PLY and OBJ
files of random triangles, each through the reader a scene uses (read_mesh_file: memory-mapped
PLY triangles, ASCII PLY in two blocks of numbers, OBJ parsed by byte columns, up to the mesh's
arrays) and through the general reader alone that it falls back to (plyfile face by face, OBJ
statements line by line), medians of wall and CPU time over repeats.
    python bench/mesh_file_speed.py [--triangles 10000 1000000] [--repeats 3] [--out FILE]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import command_line, machine, write_json  # noqa: E402

from clrender.mesh_files import obj_statements_by_line, read_mesh_file  # noqa: E402


def write_files(folder: Path, triangles: int, seed: int = 0) -> tuple[Path, Path, Path]:
    """A binary PLY, an ASCII PLY and an OBJ file of the same random mesh (triangles / 2
    vertices)."""
    rng = np.random.default_rng(seed)
    positions = rng.random((max(3, triangles // 2), 3)).astype(np.float32)
    faces = rng.integers(0, len(positions), (triangles, 3)).astype(np.int32)
    vertex = np.zeros(len(positions), [("x", "f4"), ("y", "f4"), ("z", "f4")])
    vertex["x"], vertex["y"], vertex["z"] = positions.T
    face = np.empty(triangles, [("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = faces
    ply = folder / f"mesh-{triangles}.ply"
    elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]
    PlyData(elements).write(str(ply))
    ascii_ply = folder / f"mesh-{triangles}-ascii.ply"
    PlyData(elements, text=True).write(str(ascii_ply))
    obj = folder / f"mesh-{triangles}.obj"
    with open(obj, "w") as out:
        np.savetxt(out, positions, fmt="v %.7g %.7g %.7g")
        np.savetxt(out, faces + 1, fmt="f %d %d %d")
    return ply, ascii_ply, obj


def timed(call, repeats: int) -> dict:
    walls, cpus = [], []
    for _ in range(repeats):
        cpu, start = time.process_time(), time.perf_counter()
        call()
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - cpu)
    return {"wall_s": statistics.median(walls), "cpu_s": statistics.median(cpus)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--triangles", type=int, nargs="+", default=[10_000, 1_000_000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("bench/results/mesh_file_speed.json"))
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for count in args.triangles:
            ply, ascii_ply, obj = write_files(Path(folder), count)
            readers = {
                "ply mapped": lambda ply=ply: read_mesh_file(ply),
                "ply face by face": lambda ply=ply: PlyData.read(str(ply), mmap=False),
                "ascii ply blocks": lambda path=ascii_ply: read_mesh_file(path),
                "ascii ply by face": lambda path=ascii_ply: PlyData.read(str(path), mmap=False),
                "obj columns": lambda obj=obj: read_mesh_file(obj),
                "obj line by line": lambda obj=obj: obj_statements_by_line(obj, obj.read_text()),
            }
            for name, call in readers.items():
                row = {"triangles": count, "reader": name, **timed(call, args.repeats)}
                rows.append(row)
                print(
                    f"{count:>9} {name:<17} {row['wall_s']:7.3f} s wall {row['cpu_s']:7.3f} s CPU"
                )
    write_json(
        args.out,
        {
            "command": command_line("mesh_file_speed.py", argv),
            "machine": machine(),
            "rows": rows,
        },
    )


if __name__ == "__main__":
    main()
