"""torch networks, one readable file each (training and export only; a run never imports them)."""
