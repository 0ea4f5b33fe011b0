"""Plumbing every part may use: user errors, atomic files, headless GL, MJCF loading, video writing.

It knows nothing of motion, audio, generators or backends; everything else may import it.
"""
