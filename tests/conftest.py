"""Shared test fixtures: the real assets beside the project, skipped cleanly when absent."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")

ROOT = Path(__file__).resolve().parents[1]
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))


def asset(rel: str) -> Path:
    """Path of a shared asset (e.g. "mocap/cmu_bvh/01_01.bvh"), or skip the test when it is absent."""
    p = ASSETS / rel
    if not p.exists():
        pytest.skip(f"shared asset {rel} not found under {ASSETS} (../shared/assets is absent)")
    return p


CMU_BVH = ["01_01", "02_03", "02_04", "05_02", "09_11"]

