"""FlatLab-LeRobot: a MuJoCo benchmark and LeRobot plugin for grasping flat objects."""

import os as _os

# MuJoCo must pick its GL backend before it is imported anywhere: EGL renders headless on CPU.
_os.environ.setdefault("MUJOCO_GL", "egl")
_os.environ.setdefault("PYOPENGL_PLATFORM", _os.environ["MUJOCO_GL"])

__version__ = "0.1.0"
