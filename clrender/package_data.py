"""Folders shipped beside the Python code (kernels/, scenes/): found inside an installed wheel
(pyproject force-includes them into the package) or in a source checkout / editable install,
never relative to the current working directory."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def shipped_dir(name: str, what: str) -> Path:
    """The folder `name`: inside the installed package first, else at the checkout's top."""
    packaged = Path(str(resources.files("clrender"))) / name
    if packaged.is_dir():
        return packaged
    checkout = Path(__file__).resolve().parent.parent / name
    if checkout.is_dir():
        return checkout
    raise FileNotFoundError(f"{what} not found (looked in {packaged}, {checkout})")
