"""Optuna studies over the training runner (``python -m diana_lab.sweep``): search spaces in Hydra's override
grammar, an objective on the fixed evaluation suite, studies any number of workers share, MLflow reporting."""
