"""Backend plugins: one module per body (record, render, mujoco, dynamixel, maestro).

Installed as ``convodrive.backends``. A backend knows target frames (and, for the renderer and
the recorder, canonical motion); it never imports a generator or another backend.
"""
