"""Training: the trainer, its run log and the validation curve."""
