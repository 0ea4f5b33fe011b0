"""Evaluation: figures computed from motion and audio alone, never from a generator's internals."""
