"""Start-up of the command line: a render in a new process, with PoCL's kernel cache empty (the
first render on a machine, or after an upgrade of the kernels) and filled (every later one).

    python bench/cold_start.py [--repeats K] [--args "render --res 64"] [--output DIR]

Each run is `python -m clrender <args> --json` in a child process, with POCL_CACHE_DIR pointing
at a fresh folder (cold) or at one a previous run filled (warm); runs alternate cold, warm.
Reported per kind, medians over K runs: the process's wall time and CPU time (user + system, of
the child and its threads), and from the render's JSON the parts: compile (program builds and
the kernels' warm-up launches, where PoCL generates their code; before and during the render)
and the render's own run time; the rest of the process (interpreter start, imports, device
selection, scene, writing the images) is the wall time minus the render's wall time and the
compile time before it. Also `python -m clrender --help`. JSON
goes to DIR/results.json (default bench/results/cold_start/).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import command_line, machine, write_json  # noqa: E402

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "cold_start"
KINDS = ("cold", "warm", "help")


def run_child(argv: list[str], cache_dir: Path | None, cwd: Path) -> dict:
    """Wall and CPU seconds of one `python -m clrender ...` process, and its JSON if any; PoCL's
    cache in cache_dir (None: the environment's)."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["POCL_CACHE_DIR"] = str(cache_dir)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "clrender", *argv], env=env, cwd=cwd, capture_output=True, text=True
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"python -m clrender {shlex.join(argv)} failed:\n{done.stderr.strip()}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    row = {"wall_s": wall, "cpu_s": cpu}
    if "--json" in argv:
        timings = json.loads(done.stdout)["timings"]
        row.update(
            render_wall_s=timings["wall_s"],
            compile_s=timings["compile_s"] + timings["setup_compile_s"],
            run_s=timings["run_s"],
            outside_render_s=wall - timings["wall_s"] - timings["setup_compile_s"],
        )
    return row


def medians(rows: list[dict]) -> dict:
    return {key: statistics.median(row[key] for row in rows) for key in rows[0]} | {
        "runs": len(rows)
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--args",
        default="render",
        help="the command line's arguments (default: the default render)",
    )
    parser.add_argument(
        "--user-cache",
        action="store_true",
        help="warm runs use the PoCL cache of this environment (as it is) instead of a fresh one "
        "filled by a first run",
    )
    parser.add_argument(
        "--kinds", nargs="+", choices=KINDS, default=list(KINDS), help="which starts to time"
    )
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    args = parser.parse_args(argv)
    render_argv = [*shlex.split(args.args), "--json"]
    rows: dict[str, list[dict]] = {kind: [] for kind in args.kinds}
    with tempfile.TemporaryDirectory(prefix="clrender-cold-start-") as scratch:
        scratch = Path(scratch)
        warm_cache = None if args.user_cache else scratch / "warm-cache"
        run_child(render_argv, warm_cache, scratch)  # fills the warm cache
        for k in range(args.repeats):
            for kind in args.kinds:
                if kind == "help":
                    rows[kind].append(run_child(["--help"], warm_cache, scratch))
                else:
                    cache = warm_cache if kind == "warm" else scratch / f"cold-cache-{k}"
                    rows[kind].append(run_child(render_argv, cache, scratch))
            walls = ", ".join(f"{kind} {rows[kind][-1]['wall_s']:.2f} s" for kind in args.kinds)
            print(f"run {k + 1}: {walls}", file=sys.stderr)
    summary = {kind: medians(kind_rows) for kind, kind_rows in rows.items()}
    data = {
        "command": command_line("cold_start.py", argv),
        "clrender_args": render_argv,
        "machine": machine(),
        "summary": summary,
        "runs": rows,
    }
    write_json(args.output / "results.json", data)
    for kind in ("cold", "warm"):
        if kind not in summary:
            continue
        point = summary[kind]
        print(
            f"{kind} PoCL cache: {point['wall_s']:.2f} s wall ({point['cpu_s']:.2f} s CPU): "
            f"compile {point['compile_s']:.2f} s, render {point['run_s']:.2f} s, "
            f"outside the render {point['outside_render_s']:.2f} s"
        )
    if "help" in summary:
        print(f"--help: {summary['help']['wall_s']:.2f} s wall")
    print(f"wrote {args.output / 'results.json'}")
    return data


if __name__ == "__main__":
    main()
