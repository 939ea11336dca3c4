"""Mitsuba 3 as an optional peer of the efficiency study: its built-in Cornell box (the scene
clrender's mitsuba-cbox was generated from, /work/shared/scenes-data/mitsuba-cbox.json) rendered
with its own samplers, timed like clrender's renders, and a reference of its own.

Install (optional, not a clrender dependency):

    pip install mitsuba                 # Mitsuba 3 and Dr.Jit from PyPI
    apt-get install -y libllvm19        # the LLVM JIT of its llvm_* variants (Debian)

The llvm variant finds libLLVM through DRJIT_LIBLLVM_PATH: when that is unset this module sets
it to the first libLLVM.so.19* under the usual library folders before Mitsuba loads. Without
LLVM it falls back to scalar_rgb and says so (status()["comparable_timings"] is False: a scalar
renderer's times say nothing about Mitsuba's speed).

Settings matched to clrender's mitsuba-cbox: the same resolution, box reconstruction filter
(each sample counts in its own pixel only), path integrator max_depth 9 (Mitsuba counts path
segments: clrender's depth 8 is its 9; its Russian roulette from depth 5 is left at its
default), samplers independent, stratified, multijitter, ldsampler at the study's spp, seed
varied. A render is timed from the call to the NumPy image in hand (wall: perf_counter; CPU:
process_time, which counts Dr.Jit's worker threads as they run in this process).

Reference: the mean of REFERENCE_PARTS Mitsuba renders (REFERENCE_SAMPLER, spp / parts each,
seeds REFERENCE_SEED + k) and the variance of that mean from the spread of the parts, as
bench/common.py does for clrender: Mitsuba's renders are scored against Mitsuba's reference, so
systematic differences between the two renderers do not count as error. Cached as EXR under
bench/results/references/.
"""

from __future__ import annotations

import glob
import os
import time
from pathlib import Path

import numpy as np

SAMPLERS = ("independent", "stratified", "multijitter", "ldsampler")
# Samplers whose count Mitsuba rounds: to a perfect square or a power of two.
SQUARE = ("stratified", "multijitter")
POWER_OF_TWO = ("ldsampler",)
MAX_DEPTH = 9
REFERENCE_SAMPLER = "ldsampler"
REFERENCE_PARTS = 4
REFERENCE_SEED = 5000
LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19*",
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so*",
    "/usr/lib/llvm-19/lib/libLLVM*.so*",
    "/usr/lib/*/libLLVM*.so*",
)
VARIANTS = ("llvm_ad_rgb", "scalar_rgb")


def find_libllvm() -> str | None:
    for pattern in LLVM_GLOBS:
        found = sorted(glob.glob(pattern))
        if found:
            return found[0]
    return None


class MitsubaPeer:
    """Mitsuba's Cornell box at width x height; status() says what could be had."""

    def __init__(self, width: int, height: int, log=print):
        self.width, self.height = width, height
        self.log = log
        self.mi = None
        self.variant = None
        self.why = ""
        self._scenes: dict = {}
        if not os.environ.get("DRJIT_LIBLLVM_PATH"):
            path = find_libllvm()
            if path:
                os.environ["DRJIT_LIBLLVM_PATH"] = path
        try:
            import mitsuba as mi
        except ImportError as error:
            self.why = f"mitsuba is not installed ({error}); pip install mitsuba"
            return
        errors = []
        for variant in VARIANTS:
            if variant not in mi.variants():
                errors.append(f"{variant}: not built")
                continue
            try:
                mi.set_variant(variant)
                mi.load_dict(mi.cornell_box())  # the llvm variants fail here without libLLVM
            except Exception as error:  # noqa: BLE001 - any failure means "try the next"
                errors.append(f"{variant}: {str(error).splitlines()[0][:200]}")
                continue
            self.mi, self.variant = mi, variant
            break
        else:
            self.why = "no usable variant: " + "; ".join(errors)
        self.errors = errors

    @property
    def available(self) -> bool:
        return self.mi is not None

    def status(self) -> dict:
        if not self.available:
            return {"available": False, "why": self.why}
        return {
            "available": True,
            "version": self.mi.__version__,
            "variant": self.variant,
            "comparable_timings": self.variant.startswith("llvm"),
            "libllvm": os.environ.get("DRJIT_LIBLLVM_PATH"),
            "variants_not_used": self.errors,
            "max_depth": MAX_DEPTH,
            "filter": "box",
        }

    # -----------------------------------------------------------------------------------------

    def scene_dict(self, sampler: str, spp: int) -> dict:
        scene = self.mi.cornell_box()
        sensor = scene["sensor"]
        sensor["film"]["width"], sensor["film"]["height"] = self.width, self.height
        sensor["film"]["rfilter"] = {"type": "box"}
        sensor["sampler"] = {"type": sampler, "sample_count": spp}
        scene["integrator"] = {"type": "path", "max_depth": MAX_DEPTH}
        return scene

    def scene(self, sampler: str, spp: int):
        key = (sampler, spp)
        if key not in self._scenes:
            self._scenes[key] = self.mi.load_dict(self.scene_dict(sampler, spp))
        return self._scenes[key]

    def sample_count(self, sampler: str, spp: int) -> int:
        """The count Mitsuba actually takes (it rounds where a sampler needs it)."""
        return int(self.scene(sampler, spp).sensors()[0].sampler().sample_count())

    def render(self, sampler: str, spp: int, seed: int) -> tuple[np.ndarray, dict]:
        """(image (H, W, 3) float64, timings): Mitsuba's row 0 is the top, as clrender's."""
        scene = self.scene(sampler, spp)
        cpu = time.process_time()
        start = time.perf_counter()
        image = np.array(self.mi.render(scene, seed=seed, spp=spp), dtype=np.float64)
        wall = time.perf_counter() - start
        row = {
            "renderer": "mitsuba",
            "estimator": "mitsuba",
            "sampler": sampler,
            "spp": spp,
            "spp_used": self.sample_count(sampler, spp),
            "seed": seed,
            "wall_s": wall,
            "call_s": wall,
            "cpu_s": time.process_time() - cpu,
            "load_1min": os.getloadavg()[0],
        }
        return image[..., :3], row

    def reference(
        self, spp: int, directory: Path, log=print
    ) -> tuple[np.ndarray, np.ndarray, dict]:
        """(mean image, per-pixel variance of that mean, info), cached under directory."""
        from clrender.imageio import read_exr, write_exr

        name = (
            f"mitsuba-{self.mi.__version__}_{self.variant}_{REFERENCE_SAMPLER}_"
            f"{self.width}x{self.height}_{spp}spp_d{MAX_DEPTH}_p{REFERENCE_PARTS}"
        )
        path = directory / f"{name}.exr"
        var_path = directory / f"{name}_var.exr"
        info = {
            "sampler": REFERENCE_SAMPLER,
            "spp": spp,
            "parts": REFERENCE_PARTS,
            "max_depth": MAX_DEPTH,
            "variant": self.variant,
            "path": str(path),
        }
        if path.exists() and var_path.exists():
            image, meta = read_exr(path)
            log(f"mitsuba reference: cached {path.name}")
            return (
                image.astype(np.float64),
                read_exr(var_path)[0].astype(np.float64),
                {**info, "cached": True, "wall_s": float(meta.get("wall_s", "nan"))},
            )
        part_spp = spp // REFERENCE_PARTS
        start = time.perf_counter()
        parts = []
        for k in range(REFERENCE_PARTS):
            parts.append(self.render(REFERENCE_SAMPLER, part_spp, REFERENCE_SEED + k)[0])
            log(
                f"mitsuba reference: part {k + 1}/{REFERENCE_PARTS} ({part_spp} spp) done, "
                f"{time.perf_counter() - start:.0f} s"
            )
        stack = np.stack(parts)
        mean, variance = stack.mean(axis=0), stack.var(axis=0, ddof=1) / REFERENCE_PARTS
        wall = time.perf_counter() - start
        directory.mkdir(parents=True, exist_ok=True)
        write_exr(path, mean.astype(np.float32), {"wall_s": wall, **info})
        write_exr(var_path, variance.astype(np.float32), {})
        return mean, variance, {**info, "cached": False, "wall_s": wall}
