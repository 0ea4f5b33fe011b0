"""A live preview window for rendered frames, on Tk (in the standard library).

Frames come from the offscreen GL context, so the window needs no GL of its own: it only shows
RGB images, which keeps the headless platform choice (EGL/OSMesa) untouched by the display.
"""

from __future__ import annotations

import numpy as np


class LiveWindow:
    def __init__(self, title: str) -> None:
        import tkinter

        self._tk = tkinter.Tk()
        self._tk.title(title)
        self._label = tkinter.Label(self._tk)
        self._label.pack()
        self._photo = None
        self._closed = False
        self._tk.protocol("WM_DELETE_WINDOW", self._on_close)

    def _on_close(self) -> None:
        self._closed = True

    def show(self, rgb: np.ndarray) -> None:
        """Show one (H, W, 3) uint8 frame; raises once the user has closed the window."""
        import tkinter

        if self._closed:
            raise RuntimeError("window closed")
        h, w = rgb.shape[:2]
        ppm = b"P6 %d %d 255\n" % (w, h) + np.ascontiguousarray(rgb, np.uint8).tobytes()
        self._photo = tkinter.PhotoImage(data=ppm, format="PPM")
        self._label.configure(image=self._photo)
        self._tk.update()

    def close(self) -> None:
        try:
            self._tk.destroy()
        except Exception:
            pass
