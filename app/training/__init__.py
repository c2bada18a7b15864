"""The training run every tab shares, without viser: its state, its live numbers and the notebook of runs."""
