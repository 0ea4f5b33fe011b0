"""Training recipes, one module per registered model (see ``convodrive.training.registry``)."""
