"""Shared pytest setup.  MuJoCo picks its GL backend when first imported, so the headless EGL
backend is selected here, before any test module imports mujoco."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
