"""The simulator side: MJCF models written for this project (``*.xml``), their loading with the
edits a seated body needs (``mjcf.py``), and the headless GL MuJoCo renders with (``gl.py``)."""
