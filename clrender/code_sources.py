"""The fingerprint of clrender's Python code, taken when the package is imported
(clrender.provenance.code_fingerprint). Standard library only: clrender/__init__.py computes it
before NumPy loads (clrender/__main__.py sets up the process first)."""

from __future__ import annotations

import hashlib
import os

FINGERPRINT_DIGITS = 16  # hex digits of SHA-256 kept: 64 bits, no collision among real scenes


def python_sources_fingerprint(folder: str | os.PathLike) -> str:
    """SHA-256 of the Python sources (*.py) under a folder as they are now, by path relative to
    it ("/"-separated, sorted), length and content: the same package anywhere gives the same
    value, an edited, added, removed or renamed module another. Bytecode caches, kernels and
    scenes do not count (kernels have their own fingerprint, scenes theirs)."""
    root = os.fspath(folder)
    sources = []
    for directory, subdirectories, files in os.walk(root):
        subdirectories[:] = [name for name in subdirectories if name != "__pycache__"]
        relative = os.path.relpath(directory, root)
        for name in files:
            # Modules only: not an editor's lock or backup file (Emacs' .#api.py)
            if name.endswith(".py") and name[:-3].isidentifier():
                path = name if relative == "." else f"{relative}/{name}".replace(os.sep, "/")
                sources.append((path, os.path.join(directory, name)))
    digest = hashlib.sha256()
    for path, file in sorted(sources):
        try:
            with open(file, "rb") as handle:
                content = handle.read()
        except OSError:  # unreadable: counted as such, and the import goes on
            content = b"\0unreadable"
        digest.update(f"{path}\0{len(content)}\0".encode())
        digest.update(content)
    return digest.hexdigest()[:FINGERPRINT_DIGITS]
