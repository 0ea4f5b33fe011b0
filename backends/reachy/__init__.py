"""Helpers of the ``reachy_mini`` backend: pose and limits, the daemon link, expression, tracking."""
